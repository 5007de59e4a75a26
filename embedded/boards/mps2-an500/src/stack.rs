//! The stack is painted at boot, so that how deep it ever went can be read
//! from the board's memory afterwards (qemu-board.sh reads it through
//! QEMU's monitor when the board is stopped): the lowest word that no
//! longer holds [`PAINT`] is the high-water mark.

use core::ptr::write_volatile;

/// What unused stack holds.
pub const PAINT: u32 = 0xcccc_cccc;
/// The stack's lowest address: flip-link puts the stack at the start of
/// RAM (memory.x), the statics above it.
const BOTTOM: usize = 0x2000_0000;
/// Left unpainted below the painter's own stack pointer.
const MARGIN: usize = 256;

/// Paints the stack below the caller's frame.
#[inline(never)]
pub fn paint() {
    let sp = cortex_m::register::msp::read() as usize;
    let mut at = BOTTOM;
    while at + 4 <= sp - MARGIN {
        // SAFETY: [BOTTOM, sp - MARGIN) is stack nobody uses yet, word
        // aligned, and no interrupt is enabled this early.
        unsafe { write_volatile(at as *mut u32, PAINT) };
        at += 4;
    }
}
