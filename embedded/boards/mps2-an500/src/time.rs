//! embassy-time on the two CMSDK APB timers of mps2-an500 (25 MHz PCLK, as
//! QEMU models them): TIMER0 counts down from `u32::MAX` for ever and is
//! the time base, its wrap interrupt extending it to 64 bits; TIMER1 is a
//! one-shot alarm for the timer queue's next expiration. Ticks are 1 µs
//! (feature `tick-hz-1_000_000`), 25 counts each.
//!
//! Under QEMU TCG both follow the host's clock (QEMU's virtual clock runs
//! in real time without `-icount`), so timeouts are real time, and an idle
//! board takes no interrupt until its next timer is due: no periodic tick
//! (which SysTick would need for 64-bit time), nothing between requests
//! in an instruction count.

use core::cell::{Cell, RefCell};
use core::ptr::{read_volatile, write_volatile};
use core::task::Waker;

use cortex_m::peripheral::NVIC;
use critical_section::{CriticalSection, Mutex};
use embassy_time_driver::{Driver, TICK_HZ};
use embassy_time_queue_utils::Queue;

use crate::Irq;

const TIMER0: usize = 0x4000_0000;
const TIMER1: usize = 0x4000_1000;
const CTRL: usize = 0x0;
const VALUE: usize = 0x4;
const RELOAD: usize = 0x8;
/// Read: the interrupt is pending; write 1: clear it.
const INTSTATUS: usize = 0xc;
const CTRL_ENABLE: u32 = 1 << 0;
const CTRL_IRQ_ENABLE: u32 = 1 << 3;

/// The timers' clock.
const PCLK_HZ: u64 = 25_000_000;
const COUNTS_PER_TICK: u64 = PCLK_HZ / TICK_HZ;
const _: () = assert!(
    PCLK_HZ.is_multiple_of(TICK_HZ),
    "a tick is a whole number of counts"
);

fn read(timer: usize, reg: usize) -> u32 {
    // SAFETY: a register of one of the two CMSDK timers, which only this
    // module touches.
    unsafe { read_volatile((timer + reg) as *const u32) }
}

fn write(timer: usize, reg: usize, value: u32) {
    // SAFETY: as in `read`.
    unsafe { write_volatile((timer + reg) as *mut u32, value) }
}

struct CmsdkTime {
    /// TIMER0's wraps that its interrupt has counted.
    wraps: Mutex<Cell<u32>>,
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: CmsdkTime = CmsdkTime {
    wraps: Mutex::new(Cell::new(0)),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

impl CmsdkTime {
    /// TIMER0's counts since it started.
    fn counts(&self, cs: CriticalSection<'_>) -> u64 {
        let wraps = u64::from(self.wraps.borrow(cs).get());
        let value = read(TIMER0, VALUE);
        if read(TIMER0, INTSTATUS) & 1 == 0 {
            // No wrap was pending when the value was read: it is this
            // period's.
            return wraps << 32 | u64::from(u32::MAX - value);
        }
        // A wrap its interrupt has not counted yet (interrupts are off in
        // here): the value read now is past it, unless the counter still
        // sits at 0, the last count of the old period.
        match read(TIMER0, VALUE) {
            0 => wraps << 32 | u64::from(u32::MAX),
            value => (wraps + 1) << 32 | u64::from(u32::MAX - value),
        }
    }

    /// Arms TIMER1 for tick `at`; false if `at` is already due (nothing
    /// armed). A far alarm is armed at TIMER1's range and re-armed when it
    /// fires.
    fn set_alarm(&self, cs: CriticalSection<'_>, at: u64) -> bool {
        write(TIMER1, CTRL, 0);
        write(TIMER1, INTSTATUS, 1);
        if at == u64::MAX {
            return true;
        }
        let now = self.counts(cs);
        let Some(ahead) = at
            .saturating_mul(COUNTS_PER_TICK)
            .checked_sub(now)
            .filter(|&n| n > 0)
        else {
            return false;
        };
        // RELOAD 0 makes it one-shot: it interrupts once on reaching 0.
        write(TIMER1, RELOAD, 0);
        write(TIMER1, VALUE, u32::try_from(ahead).unwrap_or(u32::MAX));
        write(TIMER1, CTRL, CTRL_ENABLE | CTRL_IRQ_ENABLE);
        true
    }

    /// Wakes what is due and arms the alarm for what is next.
    fn run_queue(&self, cs: CriticalSection<'_>) {
        let mut queue = self.queue.borrow_ref_mut(cs);
        loop {
            let next = queue.next_expiration(self.counts(cs) / COUNTS_PER_TICK);
            if self.set_alarm(cs, next) {
                return;
            }
        }
    }
}

impl Driver for CmsdkTime {
    fn now(&self) -> u64 {
        critical_section::with(|cs| self.counts(cs)) / COUNTS_PER_TICK
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            if self.queue.borrow_ref_mut(cs).schedule_wake(at, waker) {
                self.run_queue(cs);
            }
        });
    }
}

/// Starts the time base and lets both timers interrupt.
pub fn init() {
    write(TIMER0, CTRL, 0);
    // Writing RELOAD also loads the counter.
    write(TIMER0, RELOAD, u32::MAX);
    write(TIMER0, INTSTATUS, 1);
    write(TIMER0, CTRL, CTRL_ENABLE | CTRL_IRQ_ENABLE);
    write(TIMER1, CTRL, 0);
    write(TIMER1, INTSTATUS, 1);
    // SAFETY: their handlers (`on_timer0`, `on_timer1`) only take the
    // driver's critical sections.
    unsafe {
        NVIC::unmask(Irq::Timer0);
        NVIC::unmask(Irq::Timer1);
    }
}

/// TIMER0's interrupt: the time base wrapped (every 171.8 s).
pub fn on_timer0() {
    critical_section::with(|cs| {
        if read(TIMER0, INTSTATUS) & 1 != 0 {
            write(TIMER0, INTSTATUS, 1);
            let wraps = DRIVER.wraps.borrow(cs);
            wraps.set(wraps.get().wrapping_add(1));
        }
    });
}

/// TIMER1's interrupt: the alarm is due.
pub fn on_timer1() {
    critical_section::with(|cs| DRIVER.run_queue(cs));
}
