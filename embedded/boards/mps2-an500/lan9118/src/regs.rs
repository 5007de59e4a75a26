//! The controller's register map (SMSC LAN9118 datasheet, "System Control
//! and Status Registers" and "MAC Control and Status Registers"), and the
//! one abstraction every access goes through, so that the driver's
//! register sequences can be recorded and checked on the host.

/// A directly addressed register of the controller (its offset from the
/// base address). The FIFO ports are registers too: reading
/// [`Reg::RxData`] pops a word of received data, writing [`Reg::TxData`]
/// pushes one.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Reg {
    /// RX data FIFO port (read pops a word).
    RxData = 0x00,
    /// TX data FIFO port (write pushes a command or data word).
    TxData = 0x20,
    /// RX status FIFO port (read pops a frame's status).
    RxStatus = 0x40,
    /// TX status FIFO port (read pops a frame's status).
    TxStatus = 0x48,
    /// Chip id (upper half) and revision.
    IdRev = 0x50,
    /// The interrupt pin's configuration.
    IrqCfg = 0x54,
    /// Interrupt status (write 1 to clear).
    IntSts = 0x58,
    /// Interrupt enable.
    IntEn = 0x5c,
    /// Reads [`BYTE_TEST_VALUE`] when the bus and byte order are right.
    ByteTest = 0x64,
    /// FIFO levels at which interrupts are raised.
    FifoInt = 0x68,
    /// Receive configuration.
    RxCfg = 0x6c,
    /// Transmit configuration.
    TxCfg = 0x70,
    /// Hardware configuration (soft reset).
    HwCfg = 0x74,
    /// How full the RX FIFOs are.
    RxFifoInf = 0x7c,
    /// How full the TX FIFOs are.
    TxFifoInf = 0x80,
    /// Power management (the chip's ready flag).
    PmtCtrl = 0x84,
    /// Indirect access to the MAC's registers: the command.
    MacCsrCmd = 0xa4,
    /// Indirect access to the MAC's registers: the data.
    MacCsrData = 0xa8,
}

impl Reg {
    /// The register's offset from the controller's base address.
    pub const fn offset(self) -> usize {
        self as usize
    }
}

/// What [`Reg::ByteTest`] reads on a working bus.
pub const BYTE_TEST_VALUE: u32 = 0x8765_4321;

/// [`Reg::IrqCfg`]: the interrupt pin is enabled.
pub const IRQ_EN: u32 = 1 << 8;
/// [`Reg::IrqCfg`]: the pin is active high.
pub const IRQ_POL: u32 = 1 << 4;
/// [`Reg::IrqCfg`]: the pin is push-pull (not open drain).
pub const IRQ_TYPE: u32 = 1 << 0;

/// [`Reg::IntSts`]/[`Reg::IntEn`]: the RX status FIFO is above its level
/// (a frame arrived).
pub const INT_RSFL: u32 = 1 << 3;
/// [`Reg::IntSts`]/[`Reg::IntEn`]: the TX data FIFO has more room than
/// its level.
pub const INT_TDFA: u32 = 1 << 9;
/// [`Reg::IntSts`]/[`Reg::IntEn`]: the PHY's interrupt line (a link
/// change); it stays asserted until the PHY's interrupt source register is
/// read.
pub const INT_PHY: u32 = 1 << 18;

/// [`Reg::HwCfg`]: soft reset, cleared by the chip when it is done.
pub const HW_CFG_SRST: u32 = 1 << 0;
/// [`Reg::PmtCtrl`]: the chip is ready for register access.
pub const PMT_CTRL_READY: u32 = 1 << 0;

/// [`Reg::TxCfg`]: the transmitter is on.
pub const TX_CFG_TX_ON: u32 = 1 << 1;
/// [`Reg::TxCfg`]: a full TX status FIFO does not stop transmission (the
/// driver never reads the statuses).
pub const TX_CFG_TXSAO: u32 = 1 << 2;

/// [`Reg::FifoInt`]: the TX data available level, in 64-byte units.
pub const FIFO_INT_TDAL_SHIFT: u32 = 24;

/// [`Reg::MacCsrCmd`]: set to start an access; the chip clears it when done.
pub const MAC_CSR_BUSY: u32 = 1 << 31;
/// [`Reg::MacCsrCmd`]: the access is a read.
pub const MAC_CSR_READ: u32 = 1 << 30;

/// A MAC register, reached through [`Reg::MacCsrCmd`] and [`Reg::MacCsrData`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum MacReg {
    /// MAC control.
    Cr = 1,
    /// Station address, bytes 4 and 5.
    AddrH = 2,
    /// Station address, bytes 0 to 3.
    AddrL = 3,
    /// MII (PHY register) access: the command.
    MiiAcc = 6,
    /// MII access: the data.
    MiiData = 7,
}

/// [`MacReg::Cr`]: the receiver is on.
pub const MAC_CR_RXEN: u32 = 1 << 2;
/// [`MacReg::Cr`]: the transmitter is on.
pub const MAC_CR_TXEN: u32 = 1 << 3;
/// [`MacReg::Cr`]: full duplex.
pub const MAC_CR_FDPX: u32 = 1 << 20;

/// [`MacReg::MiiAcc`]: an access is under way.
pub const MII_BUSY: u32 = 1 << 0;
/// [`MacReg::MiiAcc`]: the access is a write.
pub const MII_WRITE: u32 = 1 << 1;
/// The internal PHY's address on the MII bus.
pub const PHY_ADDRESS: u32 = 1;

/// A register of the internal PHY, reached through [`MacReg::MiiAcc`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum PhyReg {
    /// Basic control.
    Bcr = 0,
    /// Basic status.
    Bsr = 1,
    /// Auto-negotiation advertisement.
    Advertise = 4,
    /// Auto-negotiation link partner ability.
    Partner = 5,
    /// Interrupt source (reading it clears it).
    IntSource = 29,
    /// Interrupt mask.
    IntMask = 30,
}

/// [`PhyReg::Bcr`]: auto-negotiation is enabled.
pub const BCR_AN_ENABLE: u16 = 1 << 12;
/// [`PhyReg::Bcr`]: restart auto-negotiation.
pub const BCR_AN_RESTART: u16 = 1 << 9;
/// [`PhyReg::Bsr`]: the link is up.
pub const BSR_LINK: u16 = 1 << 2;
/// [`PhyReg::Advertise`]/[`PhyReg::Partner`]: 100BASE-TX full duplex.
pub const ABILITY_100_FULL: u16 = 1 << 8;
/// [`PhyReg::Advertise`]/[`PhyReg::Partner`]: 10BASE-T full duplex.
pub const ABILITY_10_FULL: u16 = 1 << 6;
/// [`PhyReg::IntSource`]/[`PhyReg::IntMask`]: auto-negotiation completed.
pub const PHY_INT_AN_COMPLETE: u16 = 1 << 6;
/// [`PhyReg::IntSource`]/[`PhyReg::IntMask`]: the link went down.
pub const PHY_INT_LINK_DOWN: u16 = 1 << 4;

/// TX command A: the buffer is a frame's first segment.
pub const TX_CMD_A_FIRST: u32 = 1 << 13;
/// TX command A: last segment (the frame is sent after it).
pub const TX_CMD_A_LAST: u32 = 1 << 12;

/// RX status: the frame's length in bytes, its FCS included (bits 29:16).
pub const fn rx_status_length(status: u32) -> usize {
    ((status >> 16) & 0x3fff) as usize
}
/// RX status: error summary (CRC, too long, collision, runt, ...).
pub const RX_STATUS_ERROR: u32 = 1 << 15;
/// RX status: the address filter refused the frame (only with
/// receive-all, which this driver never sets).
pub const RX_STATUS_FILTER_FAIL: u32 = 1 << 30;

/// [`Reg::RxFifoInf`]: frames waiting in the RX status FIFO.
pub const fn rx_frames_waiting(inf: u32) -> u32 {
    (inf >> 16) & 0xff
}
/// [`Reg::TxFifoInf`]: free bytes in the TX data FIFO.
pub const fn tx_data_free(inf: u32) -> usize {
    (inf & 0xffff) as usize
}

/// 32-bit access to the controller's registers.
///
/// Both the driver (task context) and the interrupt handler hold one; the
/// registers they share are written only as the driver's comments say.
pub trait Registers {
    /// Reads `reg` (a FIFO port pops a word).
    fn read(&self, reg: Reg) -> u32;
    /// Writes `value` to `reg` (a FIFO port pushes a word).
    fn write(&self, reg: Reg, value: u32);
}

impl<R: Registers + ?Sized> Registers for &R {
    fn read(&self, reg: Reg) -> u32 {
        R::read(self, reg)
    }

    fn write(&self, reg: Reg, value: u32) {
        R::write(self, reg, value)
    }
}

/// The controller's registers in memory at a fixed address.
#[derive(Clone, Copy, Debug)]
pub struct Mmio {
    base: usize,
}

impl Mmio {
    /// The controller whose registers start at `base`.
    ///
    /// # Safety
    ///
    /// `base` must be the address of a LAN9118-family controller's 256-byte
    /// register block, mapped as device memory, and nothing but [`Mmio`]
    /// values may access it.
    pub const unsafe fn new(base: usize) -> Self {
        Mmio { base }
    }

    fn address(&self, reg: Reg) -> *mut u32 {
        (self.base + reg.offset()) as *mut u32
    }
}

// SAFETY: the registers are device memory, reachable from any context of
// the one core; the driver and its interrupt handler divide the registers
// between them as the driver documents.
unsafe impl Send for Mmio {}
// SAFETY: as for Send; every access is a single volatile word access.
unsafe impl Sync for Mmio {}

impl Registers for Mmio {
    fn read(&self, reg: Reg) -> u32 {
        // SAFETY: `Mmio::new`'s contract: a word-aligned register of the
        // controller's block.
        unsafe { core::ptr::read_volatile(self.address(reg)) }
    }

    fn write(&self, reg: Reg, value: u32) {
        // SAFETY: as in `read`.
        unsafe { core::ptr::write_volatile(self.address(reg), value) }
    }
}
