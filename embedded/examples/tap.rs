//! The embedded adapter on embassy's std platform, serving over a Linux
//! TAP interface so that real clients can reach it: the same `serve`, the
//! same connection code and the same board backend as the firmware.
//!
//! Keep its traffic in a network namespace (see the README, "Embedded"):
//!
//! ```text
//! ip netns add lluav
//! ip netns exec lluav ip tuntap add dev tap0 mode tap
//! ip netns exec lluav ip addr add 192.168.53.2/24 dev tap0
//! ip netns exec lluav ip link set tap0 up
//! ip netns exec lluav cargo run -p lluav-embedded --example tap -- --address 192.168.53.1/24
//! ```
//!
//! `--echo` serves the echo configuration for the Autobahn|Testsuite.

use std::net::Ipv4Addr;

use clap::Parser;
use embassy_executor::{Executor, Spawner};
use embassy_net::{Config as NetConfig, Ipv4Cidr, Stack, StackResources, StaticConfigV4};
use embassy_net_tuntap::TunTapDevice;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use lluav_core::{Auth, Clock, Failure, Server};
use lluav_embedded::board::{Board, Led, Peripherals};
use lluav_embedded::{Config, Echo, SharedServer, Slot, serve};

/// Concurrent sessions.
const SESSIONS: usize = 4;
/// The firmware's buffer sizes (see the firmware's main.rs).
type BoardSlot = Slot<1024, 2304, 4096, 2048>;
/// Autobahn sends text messages of up to 16 MiB and expects them echoed:
/// the message buffer and the reply (inside the transmit buffer) must
/// hold one.
const ECHO_FRAME: usize = 16 * 1024 * 1024 + 1024;
type EchoSlot = Slot<65536, { ECHO_FRAME + 16 }, ECHO_FRAME, ECHO_FRAME>;

type BoardServer = SharedServer<NoopRawMutex, Board<LoggedPeripherals>, SystemClock>;

#[derive(Parser)]
#[command(about = "LLUAV embedded adapter on a TAP interface")]
struct Args {
    /// The TAP interface to open.
    #[arg(long, default_value = "tap0")]
    tap: String,
    /// The adapter's own address and prefix on the TAP link.
    #[arg(long, default_value = "192.168.53.1/24")]
    address: String,
    /// TCP port.
    #[arg(long, default_value_t = lluav_embedded::PORT)]
    port: u16,
    /// The login password (none: every command runs without login).
    #[arg(long)]
    password: Option<String>,
    /// Echo text messages instead of serving the protocol (Autobahn|Testsuite).
    #[arg(long)]
    echo: bool,
}

/// The board's LED and PWM, shown in the log.
struct LoggedPeripherals;

impl Peripherals for LoggedPeripherals {
    fn led(&mut self, mode: Led) {
        log::info!("LED {}", mode.name());
    }

    fn pwm(&mut self, duty: u16) -> Result<(), Failure> {
        log::info!("PWM duty {duty}/65535");
        Ok(())
    }
}

/// `ts` from the host's wall clock.
struct SystemClock;

impl Clock for SystemClock {
    fn unix_ms(&self) -> i64 {
        let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH);
        now.map_or(0, |d| d.as_millis() as i64)
    }
}

#[embassy_executor::task]
async fn net_task(mut runner: embassy_net::Runner<'static, TunTapDevice>) -> ! {
    runner.run().await
}

#[embassy_executor::task]
async fn echo_task(stack: Stack<'static>, config: Config, slots: &'static mut [EchoSlot; SESSIONS]) -> ! {
    serve(stack, &config, &Echo, slots).await
}

#[embassy_executor::task]
async fn protocol_task(
    stack: Stack<'static>,
    config: Config,
    server: &'static BoardServer,
    slots: &'static mut [BoardSlot; SESSIONS],
) -> ! {
    serve(stack, &config, server, slots).await
}

fn parse_cidr(s: &str) -> Result<Ipv4Cidr, String> {
    let (ip, prefix) = s.split_once('/').ok_or("address must be IP/PREFIX")?;
    let ip: Ipv4Addr = ip.parse().map_err(|e| format!("{ip}: {e}"))?;
    let prefix: u8 = prefix.parse().map_err(|e| format!("{prefix}: {e}"))?;
    if prefix > 32 {
        return Err(format!("prefix {prefix} is over 32"));
    }
    Ok(Ipv4Cidr::new(ip, prefix))
}

fn leak<T>(value: T) -> &'static mut T {
    Box::leak(Box::new(value))
}

/// Slots as large as the echo configuration's would overflow the stack if
/// built there first, so they are allocated zeroed on the heap.
fn zeroed_slots<const N: usize, T>() -> &'static mut [T; N] {
    let layout = std::alloc::Layout::new::<[T; N]>();
    // SAFETY: the layout is not zero-sized (slots hold buffers), the
    // allocation is checked, and a Slot is only u8 arrays, for which
    // all-zero bytes are a valid value.
    unsafe {
        let slots = std::alloc::alloc_zeroed(layout).cast::<[T; N]>();
        if slots.is_null() {
            std::alloc::handle_alloc_error(layout);
        }
        &mut *slots
    }
}

fn main() -> Result<(), String> {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("info")).init();
    let args = Args::parse();
    let address = parse_cidr(&args.address)?;
    let device = TunTapDevice::new(&args.tap).map_err(|e| format!("opening TAP {}: {e}", args.tap))?;
    let net = NetConfig::ipv4_static(StaticConfigV4 {
        address,
        gateway: None,
        dns_servers: Default::default(),
    });
    let (stack, runner) =
        embassy_net::new(device, net, leak(StackResources::<{ SESSIONS + 2 }>::new()), 0x53);
    let config = Config {
        port: args.port,
        ..Config::new()
    };
    let server = if args.echo {
        None
    } else {
        let auth = Auth::new(args.password.as_deref()).map_err(|e| format!("password: {e:?}"))?;
        let board = Board::new(LoggedPeripherals);
        Some(&*leak(SharedServer::<NoopRawMutex, _, _>::new(Server::new(
            board,
            SystemClock,
            auth,
        ))))
    };
    println!("listening on ws://{}:{}", address.address(), args.port);
    leak(Executor::new()).run(move |spawner: Spawner| {
        spawner.spawn(net_task(runner).expect("one net task"));
        match server {
            None => spawner.spawn(echo_task(stack, config, zeroed_slots()).expect("one echo task")),
            Some(server) => {
                let slots = leak([const { BoardSlot::new() }; SESSIONS]);
                spawner.spawn(protocol_task(stack, config, server, slots).expect("one protocol task"))
            }
        }
    })
}
