//! The echo build (feature `echo`) for the Autobahn|Testsuite: the same
//! connection code and stack, serving `lluav_embedded::Echo`, with message
//! buffers in the board's 16 MiB of PSRAM.

use core::mem::MaybeUninit;
use core::ptr::{addr_of_mut, write_bytes};

use embassy_executor::Spawner;
use embassy_net::Stack;
use embassy_time::Duration;
use lluav_embedded::{Config, Echo, Slot, serve};

use crate::unwrap_spawn;

/// Echo sessions: Autobahn opens one at a time; the others listen.
const SESSIONS: usize = 3;
/// Sockets: one per session.
pub const SOCKETS: usize = SESSIONS;
/// 4 MiB and 1 KiB: every message of Autobahn's text cases but two (9.1.5
/// and 9.1.6, 8 and 16 MiB, do not fit this board's RAM).
const FRAME: usize = (4 << 20) + 1024;
/// 64 KiB windows each way; the echo is copied out of the message buffer
/// in pieces (`Service::ECHOES_TEXT`), so the transmit buffer need not
/// hold a whole message.
type EchoSlot = Slot<65536, 65536, FRAME, 2048>;

/// The protocol build's settings, but for a conformance run: every client
/// of the board is 10.0.2.2, so a session per slot from one address; and
/// a session closed for an oversized message (Autobahn's 8 and 16 MiB)
/// drains what its peer still sends for at most half a second, so that
/// the next cases find slots free.
const CONFIG: Config = {
    let mut config = crate::CONFIG;
    config.max_sessions_per_address = SESSIONS;
    config.max_handshakes_per_address = SESSIONS;
    config.close_timeout = Duration::from_millis(500);
    config
};

#[unsafe(link_section = ".psram")]
static mut SLOTS: MaybeUninit<[EchoSlot; SESSIONS]> = MaybeUninit::uninit();

/// The echo slots, in PSRAM (not loaded, not zeroed by the runtime).
fn slots() -> &'static mut [EchoSlot; SESSIONS] {
    // SAFETY: called once, before any task runs, so this is the only
    // reference; a slot is plain bytes, so all zeroes is a valid value.
    unsafe {
        let slots = &mut *addr_of_mut!(SLOTS);
        write_bytes(slots.as_mut_ptr(), 0, 1);
        slots.assume_init_mut()
    }
}

#[embassy_executor::task]
async fn server_task(stack: Stack<'static>, slots: &'static mut [EchoSlot; SESSIONS]) -> ! {
    serve(stack, &CONFIG, &Echo, slots).await
}

/// Serves the echo on `stack`.
pub fn start(spawner: Spawner, stack: Stack<'static>) {
    spawner.spawn(unwrap_spawn(server_task(stack, slots())));
}
