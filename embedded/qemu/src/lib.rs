//! Support for lluav-core's tests on the target ISA under QEMU: failure
//! exits through semihosting (so a failing test, a panic or a HardFault
//! ends QEMU with a failure status instead of hanging it), stack painting
//! for high-water marks, and a small vehicle backend.
#![no_std]

use cortex_m_rt::{ExceptionFrame, exception};
use cortex_m_semihosting::debug::{self, EXIT_FAILURE};
use defmt_semihosting as _;
use lluav_core::{Backend, Command, CommandId, Context, Failure, Fields, Step};

fn fail() -> ! {
    debug::exit(EXIT_FAILURE);
    // Only reached without a semihosting host.
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    defmt::error!("panicked: {}", defmt::Display2Format(info));
    fail()
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    defmt::error!("HardFault at pc {=u32:#010x}", frame.pc());
    fail()
}

/// Stack high-water marks by painting: fill the unused stack with a
/// pattern, run the code, and find the lowest word it overwrote.
pub mod stack {
    use core::ptr::{addr_of, read_volatile, write_volatile};

    const PAINT: u32 = 0xa5c3_5a3c;
    /// Room left unpainted below the painter's own stack pointer.
    const MARGIN: usize = 64;

    unsafe extern "C" {
        static _stack_end: u32;
    }

    fn bottom() -> usize {
        addr_of!(_stack_end) as usize
    }

    /// Paints the stack below the caller and returns the stack pointer
    /// from which `used_since` measures.
    #[inline(never)]
    pub fn paint() -> usize {
        let sp = cortex_m::register::msp::read() as usize;
        let mut at = bottom();
        while at + 4 <= sp - MARGIN {
            // SAFETY: [bottom, sp - MARGIN) is unused stack, word aligned,
            // and nothing else (no interrupts are enabled) writes to it.
            unsafe { write_volatile(at as *mut u32, PAINT) };
            at += 4;
        }
        sp
    }

    /// The deepest stack use below `sp` (from [`paint`]) since painting.
    pub fn used_since(sp: usize) -> usize {
        let mut at = bottom();
        // SAFETY: reads of the stack region, word aligned.
        while at < sp && unsafe { read_volatile(at as *const u32) } == PAINT {
            at += 4;
        }
        sp - at
    }
}

/// A vehicle that arms on `takeoff`, disarms on `land`/`disarm`, and for
/// `sysinfo` writes `n` bytes of padding (for the response-size limit).
pub struct Vehicle {
    /// Whether the vehicle is armed.
    pub armed: bool,
    /// Bytes of padding `sysinfo` writes.
    pub padding: usize,
}

impl Vehicle {
    /// A disarmed vehicle with a small `sysinfo`.
    pub const fn new() -> Self {
        Vehicle {
            armed: false,
            padding: 8,
        }
    }
}

impl Default for Vehicle {
    fn default() -> Self {
        Vehicle::new()
    }
}

impl Backend for Vehicle {
    fn armed(&self) -> bool {
        self.armed
    }

    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        match cmd.id() {
            CommandId::Takeoff => self.armed = true,
            CommandId::Land | CommandId::Disarm => self.armed = false,
            CommandId::State => {
                let armed = self.armed;
                out.object("state", |s| {
                    s.bool("armed", armed)
                        .str("fsm", if armed { "armed" } else { "disarmed" })
                        .bool("lock_mode", ctx.lock_mode);
                });
            }
            CommandId::Sysinfo => {
                const PAD: &str = "................................................................";
                let mut left = self.padding;
                out.array("padding", |a| {
                    while left > 0 {
                        let n = left.min(PAD.len());
                        a.str(&PAD[..n]);
                        left -= n;
                    }
                });
            }
            _ => {}
        }
        Ok(Step::Done)
    }
}
