//! embassy-executor's raw executor in thread mode, sleeping with WFI.
//!
//! embassy-executor's own Cortex-M executor sleeps with WFE, which QEMU
//! 7.2 runs as a yield: an idle board would spin a host core and add its
//! idle loop to every instruction count. WFI with interrupts masked wakes
//! on any pending interrupt (on silicon, and in QEMU, whose NVIC raises
//! its line whatever PRIMASK says), so checking for work with interrupts
//! masked and then sleeping cannot miss a wake: an interrupt that makes
//! work in between is taken as soon as they are unmasked again.

use core::sync::atomic::{AtomicBool, Ordering};

use embassy_executor::raw::Executor;

/// Set when a task was woken since the executor last looked.
static PENDED: AtomicBool = AtomicBool::new(false);

/// The executor's pender: called from tasks and interrupt handlers alike.
#[unsafe(export_name = "__pender")]
fn pender(_context: *mut ()) {
    PENDED.store(true, Ordering::Release);
}

/// Polls `executor`'s tasks for ever, sleeping when none is ready.
pub fn run(executor: &'static Executor) -> ! {
    loop {
        // SAFETY: `poll` runs only here, in thread mode, never from the
        // pender.
        unsafe { executor.poll() };
        cortex_m::interrupt::disable();
        if !PENDED.swap(false, Ordering::Acquire) {
            cortex_m::asm::wfi();
        }
        // SAFETY: no critical section is open here: this only undoes the
        // `disable` above.
        unsafe { cortex_m::interrupt::enable() };
    }
}
