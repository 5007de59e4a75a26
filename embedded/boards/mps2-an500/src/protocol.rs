//! The protocol build: lluav-core's server with the board backend, on the
//! NUCLEO-H743ZI's sessions and buffers.

use core::ptr::write_volatile;

use embassy_executor::Spawner;
use embassy_net::Stack;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use lluav_core::Failure;
use lluav_embedded::board::{Board, Led, Peripherals};
use lluav_embedded::firmware::{self, SESSIONS, SessionSlot, Uptime};
use lluav_embedded::{SharedServer, serve_slot};
use static_cell::{ConstStaticCell, StaticCell};

use crate::{CONFIG, halt, unwrap_spawn};

/// Sockets: one per session.
pub const SOCKETS: usize = SESSIONS;
/// FPGAIO's LED register: bit 0 is LED 0.
const FPGAIO_LED: usize = 0x4002_8000;

type Shared = SharedServer<CriticalSectionRawMutex, Board<Mps2>, Uptime>;
type Admission = lluav_embedded::admission::Table<SESSIONS>;

static SLOTS: ConstStaticCell<[SessionSlot; SESSIONS]> =
    ConstStaticCell::new([const { SessionSlot::new() }; SESSIONS]);
static SERVER: StaticCell<Shared> = StaticCell::new();
/// Who holds which slot, shared by the session tasks (built at boot, as
/// on the NUCLEO).
static ADMISSION: StaticCell<Admission> = StaticCell::new();
static LED: Signal<CriticalSectionRawMutex, Led> = Signal::new();

/// The board as the backend sees it: FPGAIO's LED 0, no PWM output, no
/// armed line.
struct Mps2;

impl Peripherals for Mps2 {
    fn led(&mut self, mode: Led) {
        LED.signal(mode);
    }

    fn pwm(&mut self, _duty: u16) -> Result<(), Failure> {
        Err(Failure::unsupported("No PWM output on this board"))
    }
}

#[embassy_executor::task]
async fn led_task() -> ! {
    firmware::drive_led(&LED, |lit| {
        // SAFETY: FPGAIO's LED register, written only by this task.
        unsafe { write_volatile(FPGAIO_LED as *mut u32, u32::from(lit)) }
    })
    .await
}

/// One session slot: a task each, as on the NUCLEO.
#[embassy_executor::task(pool_size = SESSIONS)]
async fn session_task(
    stack: Stack<'static>,
    server: &'static Shared,
    index: usize,
    admission: &'static Admission,
    slot: &'static mut SessionSlot,
) -> ! {
    serve_slot(stack, &CONFIG, admission, index, server, slot).await
}

/// Builds the server from the build's password and serves it on `stack`.
pub fn start(spawner: Spawner, stack: Stack<'static>) {
    let server = match firmware::server(Mps2, option_env!("LLUAV_PASSWORD")) {
        Ok(server) => server,
        Err(_) => halt("LLUAV_PASSWORD breaks the password rules"),
    };
    let server = SERVER.init(SharedServer::new(server));
    spawner.spawn(unwrap_spawn(led_task()));
    let admission = ADMISSION.init(Admission::new());
    for (index, slot) in SLOTS.take().iter_mut().enumerate() {
        spawner.spawn(unwrap_spawn(session_task(stack, server, index, admission, slot)));
    }
}
