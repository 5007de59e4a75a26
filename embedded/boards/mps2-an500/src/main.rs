//! LLUAV companion firmware for QEMU's mps2-an500 (Cortex-M7), so that the
//! firmware is tested as firmware: the same adapter, backend and limits as
//! the NUCLEO-H743ZI build (`lluav_embedded::firmware`: four sessions, the
//! same buffers), over the board's LAN9118 (our driver, `lan9118/`), with
//! an embassy-time driver on the CMSDK timers (`time.rs`) and an executor
//! that sleeps with WFI (`executor.rs`).
//!
//! The address is 10.0.2.15/24 with gateway 10.0.2.2, QEMU's user
//! networking; `bash embedded/scripts/qemu-board.sh` forwards a port of
//! 127.0.0.1 to it, so the `Host` names `127.0.0.1` and `localhost` are
//! accepted besides the board's own. FPGAIO's LED 0 follows
//! `ledon`/`ledoff`/`led_blink`; there is no PWM output and no armed line.
//! Logs are defmt frames over semihosting. A panic or a HardFault is
//! logged and ends QEMU with a failure status.
//!
//! Build with `LLUAV_PASSWORD=... cargo build --release` (qemu-board.sh
//! defaults it to `qemu-secret`). Feature `echo` serves the echo
//! configuration for the Autobahn|Testsuite instead.
#![no_std]
#![no_main]

#[cfg(feature = "echo")]
mod echo;
mod executor;
#[cfg(not(feature = "echo"))]
mod protocol;
mod stack;
mod time;

#[cfg(feature = "echo")]
use echo as served;
#[cfg(not(feature = "echo"))]
use protocol as served;

use cortex_m::interrupt::InterruptNumber;
use cortex_m::peripheral::NVIC;
use cortex_m_rt::{ExceptionFrame, entry, exception};
use cortex_m_semihosting::debug::{self, EXIT_FAILURE};
use defmt::{error, info};
use embassy_executor::raw::Executor;
use embassy_net::{Ipv4Address, Ipv4Cidr, StackResources, StaticConfigV4};
use lluav_embedded::firmware;
use lluav_lan9118::{Buffers, Lan9118, Mmio, Signals};
use static_cell::{ConstStaticCell, StaticCell};
use {defmt_semihosting as _, embassy_time::Instant};

/// The board's interrupt lines (AN500's numbering, as QEMU wires them).
#[derive(Clone, Copy)]
pub enum Irq {
    /// CMSDK TIMER0: the time base.
    Timer0 = 8,
    /// CMSDK TIMER1: the alarm.
    Timer1 = 9,
    /// The LAN9118.
    Ethernet = 13,
}

// SAFETY: the numbers are the board's external interrupt lines.
unsafe impl InterruptNumber for Irq {
    fn number(self) -> u16 {
        self as u16
    }
}

/// Where QEMU 7.2 maps the LAN9118 on mps2-an500 (`info mtree`; not
/// where the AN385 manual puts it).
const LAN9118: usize = 0xa000_0000;
const MAC: [u8; 6] = [0x02, 0x4c, 0x4c, 0x55, 0x41, 0x56];
/// QEMU's user networking: the guest's address and the host's.
const ADDRESS: Ipv4Address = Ipv4Address::new(10, 0, 2, 15);
const GATEWAY: Ipv4Address = Ipv4Address::new(10, 0, 2, 2);
/// The names the forwarded port is reached by.
pub const CONFIG: lluav_embedded::Config = firmware::config(&["127.0.0.1", "localhost"]);

type Device = Lan9118<'static, Mmio>;

static LAN: Signals = Signals::new();
static FRAMES: ConstStaticCell<Buffers> = ConstStaticCell::new(Buffers::new());
static EXECUTOR: StaticCell<Executor> = StaticCell::new();

static RESOURCES: ConstStaticCell<StackResources<{ served::SOCKETS }>> =
    ConstStaticCell::new(StackResources::new());

defmt::timestamp!("{=u64:ms}", Instant::now().as_millis());

fn lan9118() -> Mmio {
    // SAFETY: the LAN9118's register block on this board; only the driver
    // and its interrupt handler use it, as the driver documents.
    unsafe { Mmio::new(LAN9118) }
}

#[embassy_executor::task]
async fn net_task(mut runner: embassy_net::Runner<'static, Device>) -> ! {
    runner.run().await
}

/// Logs why the board cannot go on and ends QEMU with a failure status.
pub fn halt(why: &str) -> ! {
    error!("halted: {}", why);
    debug::exit(EXIT_FAILURE);
    // Only reached without a semihosting host.
    loop {
        cortex_m::asm::wfi();
    }
}

#[entry]
fn main() -> ! {
    stack::paint();
    time::init();
    info!("lluav firmware (mps2-an500) starting");

    let device = match Lan9118::new(lan9118(), &LAN, FRAMES.take(), MAC) {
        Ok(device) => device,
        Err(e) => {
            error!("LAN9118: {}", e);
            halt("no Ethernet controller")
        }
    };
    info!("LAN9118 id/rev {=u32:#010x}", device.id_rev());
    // SAFETY: its handler only touches the registers the driver leaves to it.
    unsafe { NVIC::unmask(Irq::Ethernet) };

    let config = embassy_net::Config::ipv4_static(StaticConfigV4 {
        address: Ipv4Cidr::new(ADDRESS, 24),
        gateway: Some(GATEWAY),
        dns_servers: Default::default(),
    });
    // No entropy source on this board: the seed (TCP's initial sequence
    // numbers, ephemeral ports) is the time the controller took to come
    // up, which varies with the host. A real board needs its RNG here.
    let seed = Instant::now().as_ticks() ^ 0x6c6c_7561_765f_6d70;
    let (stack, runner) = embassy_net::new(device, config, RESOURCES.take(), seed);

    let executor = EXECUTOR.init(Executor::new(core::ptr::null_mut()));
    let spawner = executor.spawner();
    spawner.spawn(unwrap_spawn(net_task(runner)));

    served::start(spawner, stack);
    info!("serving on ws://{}:{}", ADDRESS, lluav_embedded::PORT);
    executor::run(executor)
}

/// A task's spawn token: each task is spawned once, so its pool of one is free.
pub fn unwrap_spawn<T>(token: Result<T, embassy_executor::SpawnError>) -> T {
    match token {
        Ok(token) => token,
        Err(_) => halt("a task was spawned twice"),
    }
}

/// Every external interrupt, by its number: no device crate, so no table
/// of handlers of our own.
#[exception]
unsafe fn DefaultHandler(irq: i16) {
    match irq {
        8 => time::on_timer0(),
        9 => time::on_timer1(),
        13 => LAN.on_interrupt(&lan9118()),
        _ => halt("unexpected interrupt"),
    }
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    error!("HardFault at pc {=u32:#010x}", frame.pc());
    halt("HardFault")
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    error!("panicked: {}", defmt::Display2Format(info));
    halt("panic")
}
