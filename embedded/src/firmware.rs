//! What every board's firmware shares, so that a board is only its main,
//! its memory map and its drivers: the MCU's limits (DESIGN.md: four
//! sessions, a 4 KiB frame, a 2 KiB reply), the clock, the protocol server
//! built from the password the firmware was built with, the adapter's
//! settings and the user LED's rhythm.

use embassy_futures::select::{Either, select};
use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Instant, Timer};
use lluav_core::{Auth, AuthError, Clock, Server};

use crate::Config;
use crate::board::{Board, Led, Peripherals};
use crate::log::warning;
use crate::serve::Slot;

/// Concurrent WebSocket sessions.
pub const SESSIONS: usize = 4;

/// One session's buffers: the TCP receive buffer (the receive window), the
/// TCP transmit buffer (a whole 2 KiB reply and its 4-byte header, rounded
/// up), the frame limit (4 KiB on an MCU) and the reply capacity (2 KiB on
/// an MCU, written inside the transmit buffer).
pub type SessionSlot = Slot<1024, 2064, 4096, 2048>;

/// The protocol server of a board.
pub type BoardServer<P> = Server<Board<P>, Uptime>;

/// `ts` without a wall clock: milliseconds since boot.
#[derive(Clone, Copy, Debug, Default)]
pub struct Uptime;

impl Clock for Uptime {
    fn unix_ms(&self) -> i64 {
        Instant::now().as_millis() as i64
    }
}

/// The protocol server for a board with `peripherals`, requiring
/// `password` (the firmware's `option_env!("LLUAV_PASSWORD")`); without
/// one every command runs without login, which is logged as a warning.
/// A password that breaks the rules is refused.
pub fn server<P: Peripherals>(peripherals: P, password: Option<&str>) -> Result<BoardServer<P>, AuthError> {
    if password.is_none() {
        warning!("built without LLUAV_PASSWORD: every command runs without login");
    }
    let auth = Auth::new(password)?;
    Ok(Server::new(Board::new(peripherals), Uptime, auth))
}

/// The adapter's settings on a board, accepting the `Host` names in
/// `hosts` besides the board's own address (e.g. the names a port
/// forwarder reaches it by).
pub const fn config(hosts: &'static [&'static str]) -> Config {
    let mut config = Config::new();
    config.allowed_hosts = hosts;
    config
}

/// Drives the user LED for ever: `set(true)` lights it. It follows what
/// the backend signals; blinking toggles it every 250 ms.
pub async fn drive_led<M: RawMutex>(signal: &Signal<M, Led>, mut set: impl FnMut(bool)) -> ! {
    let mut mode = Led::Off;
    let mut lit = false;
    loop {
        lit = match mode {
            Led::Off => false,
            Led::On => true,
            Led::Blink => !lit,
        };
        set(lit);
        mode = match mode {
            Led::Blink => match select(signal.wait(), Timer::after_millis(250)).await {
                Either::First(next) => next,
                Either::Second(()) => Led::Blink,
            },
            _ => signal.wait().await,
        };
    }
}
