//! The echo build (feature `echo`) for the Autobahn|Testsuite: the same
//! connection code and stack, serving `lluav_embedded::Echo`, its text
//! streamed (`lluav-embedded/streamed-echo`): a text message passes
//! through the message buffer a piece at a time and goes back as a
//! fragmented message, so Autobahn's 16 MiB messages need no more memory
//! than its smallest. The slots are in the board's PSRAM (too large for
//! the 512 KiB of RAM the firmware is given, as on the NUCLEO).

use core::mem::MaybeUninit;
use core::ptr::{addr_of_mut, write_bytes};

use embassy_executor::Spawner;
use embassy_net::Stack;
use lluav_embedded::{Config, Echo, Slot, serve};

use crate::unwrap_spawn;

/// Echo sessions: Autobahn opens one at a time; the others listen.
const SESSIONS: usize = 3;
/// Sockets: one per session.
pub const SOCKETS: usize = SESSIONS;
/// The message buffer: the upgrade request's head, then one piece of a
/// text message at a time (each piece one frame of the echo: 1,024 frames
/// for a 16 MiB message), or a whole binary message for the echo to
/// refuse (1003; a longer one is oversized, 1009).
const FRAME: usize = 16 * 1024;
/// 64 KiB windows each way (Autobahn's largest messages through QEMU's
/// user networking); the pieces are copied into the transmit buffer as
/// its free space takes them, so it need not hold one whole.
type EchoSlot = Slot<65536, 65536, FRAME, 2048>;

/// The protocol build's settings, but for a conformance run: every client
/// of the board is 10.0.2.2, so a session per slot from one address.
const CONFIG: Config = {
    let mut config = crate::CONFIG;
    config.max_sessions_per_address = SESSIONS;
    config.max_handshakes_per_address = SESSIONS;
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
