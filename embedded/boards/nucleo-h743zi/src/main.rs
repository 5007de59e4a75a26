//! LLUAV companion firmware for the NUCLEO-H743ZI: the protocol on port
//! 53001 over the on-board Ethernet (DHCP, static fallback), four
//! concurrent sessions, LD3 (red, PB14) for `ledon`/`ledoff`/`led_blink`,
//! LD1 (green, PB0, TIM3 channel 3) for `ledpwm`, and the user button B1
//! (PC13) standing in for the autopilot's armed line (held = armed).
//!
//! Build with `LLUAV_PASSWORD=... cargo build --release`; without it every
//! command runs without login (a warning is logged at boot).
#![no_std]
#![no_main]

use core::mem::MaybeUninit;

use defmt::{info, unwrap, warn};
use embassy_executor::Spawner;
use embassy_net::{Ipv4Address, Ipv4Cidr, StackResources, StaticConfigV4};
use embassy_stm32::eth::{Ethernet, GenericPhy, PacketQueue, Sma};
use embassy_stm32::exti::{self, ExtiInput};
use embassy_stm32::gpio::{Level, Output, OutputType, Pull, Speed};
use embassy_stm32::mode::Async;
use embassy_stm32::peripherals::{ETH, ETH_SMA, RNG, TIM3};
use embassy_stm32::rng::{self, Rng};
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::low_level::CountingMode;
use embassy_stm32::timer::simple_pwm::{PwmPin, SimplePwm, SimplePwmChannel};
use embassy_stm32::{Config, bind_interrupts, eth, interrupt};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, with_timeout};
use lluav_core::Failure;
use lluav_embedded::SharedServer;
use lluav_embedded::board::{Board, Led, Peripherals};
use lluav_embedded::firmware::{self, SESSIONS, SessionSlot, Uptime};
use static_cell::{ConstStaticCell, StaticCell};
use {defmt_rtt as _, panic_probe as _};

bind_interrupts!(struct Irqs {
    ETH => eth::InterruptHandler;
    RNG => rng::InterruptHandler<RNG>;
    EXTI15_10 => exti::InterruptHandler<interrupt::typelevel::EXTI15_10>;
});

/// The address used when no DHCP server answers in time.
const FALLBACK: Ipv4Address = Ipv4Address::new(192, 168, 1, 53);
const DHCP_TIMEOUT: Duration = Duration::from_secs(10);
const MAC: [u8; 6] = [0x02, 0x4c, 0x4c, 0x55, 0x41, 0x56];

type Device = Ethernet<'static, ETH, GenericPhy<Sma<'static, ETH_SMA>>>;
type Shared = SharedServer<CriticalSectionRawMutex, Board<Nucleo>, Uptime>;
type Admission = lluav_embedded::admission::Table<SESSIONS>;

/// Ethernet DMA buffers: two for sending (a reply of up to 2 KiB is two
/// segments; smoltcp waits for a free one) and four for receiving (bursts
/// from several clients), 1.5 KB each.
type Packets = PacketQueue<2, 4>;

// Large statics are initialised in place: built by value in a task they
// would sit on the stack first (a 19 KB frame was seen for PacketQueue).
static PACKETS: StaticCell<Packets> = StaticCell::new();
static SLOTS: ConstStaticCell<[SessionSlot; SESSIONS]> =
    ConstStaticCell::new([const { SessionSlot::new() }; SESSIONS]);
/// One socket per session and one for DHCP.
static RESOURCES: ConstStaticCell<StackResources<{ SESSIONS + 1 }>> =
    ConstStaticCell::new(StackResources::new());
static SERVER: StaticCell<Shared> = StaticCell::new();
/// Who holds which slot, shared by the session tasks. Built at boot, not
/// initialised in place: its idle state is not all zeroes, and as `.data`
/// it would take 440 bytes of flash.
static ADMISSION: StaticCell<Admission> = StaticCell::new();
static LED: Signal<CriticalSectionRawMutex, Led> = Signal::new();

/// The NUCLEO's LEDs: LD3 follows the LED task, LD1 is the PWM output.
struct Nucleo {
    pwm: SimplePwmChannel<'static, TIM3>,
}

impl Peripherals for Nucleo {
    fn led(&mut self, mode: Led) {
        LED.signal(mode);
    }

    fn pwm(&mut self, duty: u16) -> Result<(), Failure> {
        self.pwm
            .set_duty_cycle_fraction(u32::from(duty), u32::from(u16::MAX));
        Ok(())
    }
}

#[embassy_executor::task]
async fn net_task(mut runner: embassy_net::Runner<'static, Device>) -> ! {
    runner.run().await
}

#[embassy_executor::task]
async fn led_task(mut led: Output<'static>) -> ! {
    firmware::drive_led(&LED, |lit| led.set_level(Level::from(lit))).await
}

/// Mirrors the armed line (B1, active high) into the backend.
#[embassy_executor::task]
async fn armed_task(mut line: ExtiInput<'static, Async>, server: &'static Shared) -> ! {
    loop {
        let armed = line.is_high();
        server.lock().await.backend_mut().set_armed(armed);
        info!("armed: {}", armed);
        line.wait_for_any_edge().await;
    }
}

/// One session slot: a task each, so that a connection's state lives in
/// its task's static storage (joined in one task, four connections' futures
/// were copied through a 10 KB stack frame).
#[embassy_executor::task(pool_size = SESSIONS)]
async fn session_task(
    stack: embassy_net::Stack<'static>,
    server: &'static Shared,
    index: usize,
    admission: &'static Admission,
    slot: &'static mut SessionSlot,
) -> ! {
    lluav_embedded::serve_slot(stack, &CONFIG, admission, index, server, slot).await
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(clocks());
    info!("lluav firmware starting");

    let mut rng = Rng::new(p.RNG, Irqs);
    let mut seed = [0; 8];
    rng.fill_bytes(&mut seed);

    let packets: &'static mut MaybeUninit<Packets> = PACKETS.uninit();
    PacketQueue::init(packets);
    // SAFETY: PacketQueue::init initialises the whole queue in place.
    let packets = unsafe { packets.assume_init_mut() };
    let device = Ethernet::new(
        packets, p.ETH, Irqs, p.PA1, p.PA7, p.PC4, p.PC5, p.PG13, p.PB13, p.PG11, MAC, p.ETH_SMA, p.PA2,
        p.PC1,
    );
    let (stack, runner) = embassy_net::new(
        device,
        embassy_net::Config::dhcpv4(Default::default()),
        RESOURCES.take(),
        u64::from_le_bytes(seed),
    );
    spawner.spawn(unwrap!(net_task(runner)));

    let mut pwm = SimplePwm::new(
        p.TIM3,
        None,
        None,
        Some(PwmPin::new(p.PB0, OutputType::PushPull)),
        None,
        Hertz::khz(1),
        CountingMode::EdgeAlignedUp,
    )
    .split()
    .ch3;
    pwm.set_duty_cycle_fully_off();
    pwm.enable();
    spawner.spawn(unwrap!(led_task(Output::new(p.PB14, Level::Low, Speed::Low))));

    let server = unwrap!(firmware::server(Nucleo { pwm }, option_env!("LLUAV_PASSWORD")).ok());
    let server = SERVER.init(SharedServer::new(server));
    let armed_line = ExtiInput::new(p.PC13, p.EXTI13, Pull::Down, Irqs);
    spawner.spawn(unwrap!(armed_task(armed_line, server)));

    stack.wait_link_up().await;
    if with_timeout(DHCP_TIMEOUT, stack.wait_config_up()).await.is_err() {
        warn!("no DHCP lease: falling back to {}", FALLBACK);
        stack.set_config_v4(embassy_net::ConfigV4::Static(StaticConfigV4 {
            address: Ipv4Cidr::new(FALLBACK, 24),
            gateway: None,
            dns_servers: Default::default(),
        }));
    }
    if let Some(config) = stack.config_v4() {
        info!(
            "serving on ws://{}:{}",
            config.address.address(),
            lluav_embedded::PORT
        );
    }
    let admission = ADMISSION.init(Admission::new());
    for (index, slot) in SLOTS.take().iter_mut().enumerate() {
        spawner.spawn(unwrap!(session_task(stack, server, index, admission, slot)));
    }
}

/// The adapter's settings: in flash, not built at run time.
const CONFIG: lluav_embedded::Config = firmware::config(&[]);

/// 400 MHz from the internal oscillator; the Ethernet MAC runs from AHB.
fn clocks() -> Config {
    use embassy_stm32::rcc::*;
    let mut config = embassy_stm32::Config::default();
    config.rcc.hsi = Some(HSIPrescaler::DIV1);
    config.rcc.csi = true;
    config.rcc.hsi48 = Some(Hsi48Config { sync_from_usb: true });
    config.rcc.pll1 = Some(Pll {
        source: PllSource::HSI,
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL50,
        fracn: None,
        divp: Some(PllDiv::DIV2),
        divq: Some(PllDiv::DIV8),
        divr: None,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.ahb_pre = AHBPrescaler::DIV2;
    config.rcc.apb1_pre = APBPrescaler::DIV2;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.apb3_pre = APBPrescaler::DIV2;
    config.rcc.apb4_pre = APBPrescaler::DIV2;
    config.rcc.voltage_scale = VoltageScale::Scale1;
    config.rcc.mux.rngsel = mux::Rngsel::HSI48;
    config
}
