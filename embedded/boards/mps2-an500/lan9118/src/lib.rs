//! An [embassy-net](embassy_net_driver) driver for the SMSC LAN9118 family
//! of Ethernet controllers (the LAN9220 of ARM's MPS2 boards, which QEMU
//! models as `lan9118`), in 32-bit PIO mode: frames go through the chip's
//! FIFO ports word by word, no DMA.
//!
//! Every register access goes through [`Registers`], so the sequences the
//! driver relies on (the soft reset, indirect MAC and PHY access, TX
//! commands A and B before the data, RX status before the data) are checked
//! on the host against a recorded register block (`tests/`). On the board
//! the registers are [`Mmio`]; the board's interrupt handler for the chip
//! calls [`Signals::on_interrupt`].
//!
//! What the driver asks of the chip:
//! - **Receive**: an interrupt when the RX status FIFO holds a frame
//!   (`RSFL`, level 0), acknowledged by the handler; the driver then pops
//!   the status, reads the frame's words into its receive buffer (dropping
//!   the FCS) and hands them to the stack. A frame with an error is read
//!   out and dropped (reading is always valid; the chip's fast-forward is
//!   not needed for the few short frames that fail).
//! - **Transmit**: a frame is one buffer (first and last segment), 4-byte
//!   end alignment, no offset: command A, command B, then the words. The
//!   driver hands out a transmit token only when the TX data FIFO has room
//!   for the largest frame; otherwise it asks for the `TDFA` interrupt. TX
//!   statuses are never read (`TXSAO` lets the status FIFO overrun).
//! - **Link**: the PHY's interrupt (auto-negotiation complete, link down)
//!   is masked by the handler and unmasked by the driver after it has read
//!   the PHY's interrupt source and status; the MAC's duplex follows what
//!   both ends advertise.
//!
//! Nothing here panics: buffers are sized for the largest frame, lengths
//! read from the chip are checked, and every wait for the chip is bounded
//! ([`Error::Timeout`]).
#![no_std]
#![deny(
    clippy::indexing_slicing,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    unsafe_op_in_unsafe_fn
)]
#![warn(missing_docs)]

pub mod regs;

use core::sync::atomic::{AtomicBool, Ordering};
use core::task::Context;

use embassy_net_driver::{Capabilities, HardwareAddress, LinkState};
use embassy_sync::waitqueue::AtomicWaker;

use regs::*;
pub use regs::{Mmio, Reg, Registers};

/// The largest frame handed to or taken from the stack: 1500 bytes of
/// payload and the 14-byte Ethernet header (no FCS).
pub const MTU: usize = 1514;
/// Bytes of each frame buffer: the largest frame the chip may report (a
/// VLAN-tagged one and its FCS), in whole words.
pub const BUFFER: usize = 1536;
/// The FCS at the end of every received frame.
const FCS: usize = 4;
/// The smallest frame the chip reports: an Ethernet header and the FCS.
const MIN_FRAME: usize = 14 + FCS;
/// Room a frame of [`MTU`] bytes takes in the TX data FIFO: its words and
/// commands A and B.
const TX_ROOM: usize = MTU.div_ceil(4) * 4 + 8;
/// How often a register is polled while waiting for the chip before the
/// driver gives up (the chip answers within microseconds).
const POLLS: u32 = 100_000;

/// Why the controller could not be used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// `BYTE_TEST` did not read `0x87654321`: no controller at that
    /// address, or a bus of another width or byte order.
    NotFound {
        /// What `BYTE_TEST` read.
        byte_test: u32,
    },
    /// The chip did not finish in time.
    Timeout(Wait),
}

/// What the driver was waiting for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Wait {
    /// The soft reset to end.
    Reset,
    /// The chip to report itself ready.
    Ready,
    /// An indirect MAC register access.
    MacCsr,
    /// An MII (PHY register) access.
    Mii,
}

/// The frame buffers: one for the frame received last, one for the frame
/// being sent. `const`, so a board can keep them in a static initialised
/// in place.
pub struct Buffers {
    rx: [u8; BUFFER],
    tx: [u8; BUFFER],
}

impl Buffers {
    /// Zeroed buffers.
    pub const fn new() -> Self {
        Buffers {
            rx: [0; BUFFER],
            tx: [0; BUFFER],
        }
    }
}

impl Default for Buffers {
    fn default() -> Self {
        Buffers::new()
    }
}

/// What the interrupt handler and the driver share: whom to wake.
pub struct Signals {
    rx: AtomicWaker,
    tx: AtomicWaker,
    link: AtomicWaker,
    /// The PHY interrupted (or nothing is known yet): the driver reads the
    /// PHY at its next link check.
    phy_event: AtomicBool,
}

impl Signals {
    /// Nobody to wake yet; the first link check reads the PHY.
    pub const fn new() -> Self {
        Signals {
            rx: AtomicWaker::new(),
            tx: AtomicWaker::new(),
            link: AtomicWaker::new(),
            phy_event: AtomicBool::new(true),
        }
    }

    /// The chip's interrupt handler: acknowledges what is pending and
    /// wakes the driver. `TDFA` and the PHY's line stay asserted while
    /// their condition holds, so they are masked here and unmasked by the
    /// driver when it wants them again; `RSFL` is latched and only
    /// acknowledged.
    pub fn on_interrupt(&self, regs: &impl Registers) {
        let enabled = regs.read(Reg::IntEn);
        let pending = regs.read(Reg::IntSts) & enabled;
        let level = pending & (INT_TDFA | INT_PHY);
        if level != 0 {
            // The driver changes INT_EN only in a critical section, so this
            // read-modify-write cannot interleave with one of its own.
            regs.write(Reg::IntEn, enabled & !level);
        }
        regs.write(Reg::IntSts, pending);
        if pending & INT_RSFL != 0 {
            self.rx.wake();
        }
        if pending & INT_TDFA != 0 {
            self.tx.wake();
        }
        if pending & INT_PHY != 0 {
            self.phy_event.store(true, Ordering::Release);
            self.link.wake();
        }
    }
}

impl Default for Signals {
    fn default() -> Self {
        Signals::new()
    }
}

/// The controller, configured and running.
pub struct Lan9118<'d, R: Registers> {
    regs: R,
    signals: &'d Signals,
    buffers: &'d mut Buffers,
    mac: [u8; 6],
    id_rev: u32,
    link: LinkState,
    dropped: u32,
}

impl<'d, R: Registers> Lan9118<'d, R> {
    /// Resets the controller behind `regs` and configures it: station
    /// address `mac`, auto-negotiation restarted, receiver and transmitter
    /// on, interrupts for received frames and link changes on an
    /// active-high push-pull pin (enable the board's interrupt line after
    /// this returns).
    pub fn new(regs: R, signals: &'d Signals, buffers: &'d mut Buffers, mac: [u8; 6]) -> Result<Self, Error> {
        let byte_test = regs.read(Reg::ByteTest);
        if byte_test != BYTE_TEST_VALUE {
            return Err(Error::NotFound { byte_test });
        }
        let id_rev = regs.read(Reg::IdRev);
        let chip = Lan9118 {
            regs,
            signals,
            buffers,
            mac,
            id_rev,
            link: LinkState::Down,
            dropped: 0,
        };
        chip.regs.write(Reg::HwCfg, HW_CFG_SRST);
        chip.wait(Wait::Reset, |r| r.read(Reg::HwCfg) & HW_CFG_SRST == 0)?;
        chip.wait(Wait::Ready, |r| r.read(Reg::PmtCtrl) & PMT_CTRL_READY != 0)?;
        // Nothing may interrupt until the chip is configured.
        chip.regs.write(Reg::IntEn, 0);
        chip.regs.write(Reg::IntSts, u32::MAX);

        let [a0, a1, a2, a3, a4, a5] = mac.map(u32::from);
        chip.mac_write(MacReg::AddrL, a0 | a1 << 8 | a2 << 16 | a3 << 24)?;
        chip.mac_write(MacReg::AddrH, a4 | a5 << 8)?;
        chip.phy_write(PhyReg::Bcr, BCR_AN_ENABLE | BCR_AN_RESTART)?;
        chip.phy_write(PhyReg::IntMask, PHY_INT_AN_COMPLETE | PHY_INT_LINK_DOWN)?;

        // An interrupt for every frame (RX status level 0), and, when asked
        // for, one when the largest frame fits the TX data FIFO.
        let tdal = TX_ROOM.div_ceil(64) as u32;
        chip.regs.write(Reg::FifoInt, tdal << FIFO_INT_TDAL_SHIFT);
        // No RX offset, 4-byte end alignment: a frame is just its words.
        chip.regs.write(Reg::RxCfg, 0);
        chip.regs.write(Reg::TxCfg, TX_CFG_TX_ON | TX_CFG_TXSAO);
        chip.mac_write(MacReg::Cr, MAC_CR_TXEN | MAC_CR_RXEN)?;

        chip.regs.write(Reg::IntSts, u32::MAX);
        chip.regs.write(Reg::IntEn, INT_RSFL | INT_PHY);
        chip.regs.write(Reg::IrqCfg, IRQ_EN | IRQ_POL | IRQ_TYPE);
        Ok(chip)
    }

    /// `ID_REV`: the chip's id (upper 16 bits, e.g. `0x0118` or `0x9220`)
    /// and revision.
    pub fn id_rev(&self) -> u32 {
        self.id_rev
    }

    /// Frames dropped so far: received with errors, or not sent because
    /// the TX FIFO stayed full.
    pub fn dropped(&self) -> u32 {
        self.dropped
    }

    /// Polls the chip until `done`, at most [`POLLS`] times.
    fn wait(&self, what: Wait, done: impl Fn(&R) -> bool) -> Result<(), Error> {
        if (0..POLLS).any(|_| done(&self.regs)) {
            Ok(())
        } else {
            Err(Error::Timeout(what))
        }
    }

    /// Writes a MAC register: the data first, then the command.
    fn mac_write(&self, reg: MacReg, value: u32) -> Result<(), Error> {
        self.wait(Wait::MacCsr, |r| r.read(Reg::MacCsrCmd) & MAC_CSR_BUSY == 0)?;
        self.regs.write(Reg::MacCsrData, value);
        self.regs.write(Reg::MacCsrCmd, MAC_CSR_BUSY | reg as u32);
        self.wait(Wait::MacCsr, |r| r.read(Reg::MacCsrCmd) & MAC_CSR_BUSY == 0)
    }

    /// Reads a MAC register: the command, then the data once it is done.
    fn mac_read(&self, reg: MacReg) -> Result<u32, Error> {
        self.wait(Wait::MacCsr, |r| r.read(Reg::MacCsrCmd) & MAC_CSR_BUSY == 0)?;
        self.regs
            .write(Reg::MacCsrCmd, MAC_CSR_BUSY | MAC_CSR_READ | reg as u32);
        self.wait(Wait::MacCsr, |r| r.read(Reg::MacCsrCmd) & MAC_CSR_BUSY == 0)?;
        Ok(self.regs.read(Reg::MacCsrData))
    }

    fn mii_idle(&self) -> Result<(), Error> {
        for _ in 0..POLLS {
            if self.mac_read(MacReg::MiiAcc)? & MII_BUSY == 0 {
                return Ok(());
            }
        }
        Err(Error::Timeout(Wait::Mii))
    }

    fn mii_command(reg: PhyReg) -> u32 {
        PHY_ADDRESS << 11 | (reg as u32) << 6 | MII_BUSY
    }

    /// Reads a register of the internal PHY through the MAC's MII port.
    fn phy_read(&self, reg: PhyReg) -> Result<u16, Error> {
        self.mii_idle()?;
        self.mac_write(MacReg::MiiAcc, Self::mii_command(reg))?;
        self.mii_idle()?;
        Ok(self.mac_read(MacReg::MiiData)? as u16)
    }

    /// Writes a register of the internal PHY through the MAC's MII port.
    fn phy_write(&self, reg: PhyReg, value: u16) -> Result<(), Error> {
        self.mii_idle()?;
        self.mac_write(MacReg::MiiData, u32::from(value))?;
        self.mac_write(MacReg::MiiAcc, Self::mii_command(reg) | MII_WRITE)?;
        self.mii_idle()
    }

    /// Turns interrupt sources on; the handler turns `TDFA` and the PHY's
    /// off again, so the read-modify-write must not be interrupted.
    fn unmask(&self, bits: u32) {
        critical_section::with(|_| {
            let enabled = self.regs.read(Reg::IntEn);
            self.regs.write(Reg::IntEn, enabled | bits);
        });
    }

    /// Reads the PHY after it interrupted: its interrupt source (which
    /// clears the interrupt), then the link, and sets the MAC's duplex to
    /// what both ends advertise.
    fn read_link(&self) -> Result<LinkState, Error> {
        self.phy_read(PhyReg::IntSource)?;
        // The link bit latches low: the first read reports a drop since
        // the last read, the second the link as it is now.
        self.phy_read(PhyReg::Bsr)?;
        if self.phy_read(PhyReg::Bsr)? & BSR_LINK == 0 {
            return Ok(LinkState::Down);
        }
        let common = self.phy_read(PhyReg::Advertise)? & self.phy_read(PhyReg::Partner)?;
        let duplex = if common & (ABILITY_100_FULL | ABILITY_10_FULL) != 0 {
            MAC_CR_FDPX
        } else {
            0
        };
        self.mac_write(MacReg::Cr, MAC_CR_TXEN | MAC_CR_RXEN | duplex)?;
        Ok(LinkState::Up)
    }

    fn tx_room(&self) -> bool {
        tx_data_free(self.regs.read(Reg::TxFifoInf)) >= TX_ROOM
    }
}

impl<R: Registers> embassy_net_driver::Driver for Lan9118<'_, R> {
    type RxToken<'a>
        = RxToken<'a>
    where
        Self: 'a;
    type TxToken<'a>
        = TxToken<'a, R>
    where
        Self: 'a;

    fn receive(&mut self, cx: &mut Context<'_>) -> Option<(RxToken<'_>, TxToken<'_, R>)> {
        // Registered before looking, so a frame that arrives after the
        // look wakes this task through RSFL.
        self.signals.rx.register(cx.waker());
        let Buffers { rx, tx } = &mut *self.buffers;
        loop {
            if rx_frames_waiting(self.regs.read(Reg::RxFifoInf)) == 0 {
                return None;
            }
            let status = self.regs.read(Reg::RxStatus);
            let length = rx_status_length(status);
            let words = length.div_ceil(4);
            let good = status & (RX_STATUS_ERROR | RX_STATUS_FILTER_FAIL) == 0
                && (MIN_FRAME..=BUFFER).contains(&length);
            if !good {
                for _ in 0..words {
                    self.regs.read(Reg::RxData);
                }
                self.dropped = self.dropped.wrapping_add(1);
                continue;
            }
            for word in rx.chunks_exact_mut(4).take(words) {
                word.copy_from_slice(&self.regs.read(Reg::RxData).to_le_bytes());
            }
            let frame = rx.get_mut(..length - FCS)?;
            let tx = TxToken {
                regs: &self.regs,
                buffer: tx,
                dropped: &mut self.dropped,
            };
            return Some((RxToken { frame }, tx));
        }
    }

    fn transmit(&mut self, cx: &mut Context<'_>) -> Option<TxToken<'_, R>> {
        self.signals.tx.register(cx.waker());
        if !self.tx_room() {
            // TDFA is level-triggered: if room appeared meanwhile, it
            // interrupts as soon as it is unmasked.
            self.unmask(INT_TDFA);
            return None;
        }
        Some(TxToken {
            regs: &self.regs,
            buffer: &mut self.buffers.tx,
            dropped: &mut self.dropped,
        })
    }

    fn link_state(&mut self, cx: &mut Context<'_>) -> LinkState {
        self.signals.link.register(cx.waker());
        if self.signals.phy_event.swap(false, Ordering::AcqRel) {
            // A PHY that does not answer counts as no link; its next
            // interrupt reads it again.
            self.link = self.read_link().unwrap_or(LinkState::Down);
            self.unmask(INT_PHY);
        }
        self.link
    }

    fn capabilities(&self) -> Capabilities {
        let mut caps = Capabilities::default();
        caps.max_transmission_unit = MTU;
        caps
    }

    fn hardware_address(&self) -> HardwareAddress {
        HardwareAddress::Ethernet(self.mac)
    }
}

/// A received frame, in the driver's receive buffer.
pub struct RxToken<'a> {
    frame: &'a mut [u8],
}

impl embassy_net_driver::RxToken for RxToken<'_> {
    fn consume<T, F>(self, f: F) -> T
    where
        F: FnOnce(&mut [u8]) -> T,
    {
        f(self.frame)
    }
}

/// Room for one frame: the stack writes it into the transmit buffer, then
/// it goes into the TX data FIFO.
pub struct TxToken<'a, R> {
    regs: &'a R,
    buffer: &'a mut [u8; BUFFER],
    dropped: &'a mut u32,
}

impl<R: Registers> embassy_net_driver::TxToken for TxToken<'_, R> {
    fn consume<T, F>(self, len: usize, f: F) -> T
    where
        F: FnOnce(&mut [u8]) -> T,
    {
        // The stack asks for at most the MTU; anything longer is cut
        // rather than indexed out of range.
        let (frame, _) = self.buffer.split_at_mut(len.min(MTU));
        let result = f(frame);
        // A token paired with a received frame was handed out without
        // looking at the FIFO: wait for it to drain (it sends at line
        // rate), or drop the frame.
        if (0..POLLS).any(|_| tx_data_free(self.regs.read(Reg::TxFifoInf)) >= TX_ROOM) {
            send(self.regs, frame);
        } else {
            *self.dropped = self.dropped.wrapping_add(1);
        }
        result
    }
}

/// Pushes `frame` into the TX data FIFO as one segment: command A
/// (first and last segment, its length), command B (its length), then
/// its bytes as little-endian words, the last one padded.
fn send(regs: &impl Registers, frame: &[u8]) {
    let length = frame.len() as u32;
    regs.write(Reg::TxData, TX_CMD_A_FIRST | TX_CMD_A_LAST | length);
    regs.write(Reg::TxData, length);
    let words = frame.chunks_exact(4);
    let tail = words.remainder();
    for word in words {
        if let Ok(bytes) = <[u8; 4]>::try_from(word) {
            regs.write(Reg::TxData, u32::from_le_bytes(bytes));
        }
    }
    if !tail.is_empty() {
        let last = tail
            .iter()
            .enumerate()
            .fold(0, |w, (i, &b)| w | u32::from(b) << (8 * i));
        regs.write(Reg::TxData, last);
    }
}
