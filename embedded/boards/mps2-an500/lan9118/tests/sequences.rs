//! The register sequences the driver relies on, against a recorded
//! register block: every access is logged, FIFO ports and status registers
//! answer what a test scripts, and the indirect MAC and PHY registers
//! behave as the datasheet describes (the data register, then the command
//! with the busy bit; MII access through the MAC), so a test can look at
//! both the bus traffic and the state it left.

use std::cell::RefCell;
use std::collections::{HashMap, VecDeque};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::task::{Context, Wake, Waker};

use embassy_net_driver::{Driver, LinkState, RxToken as _, TxToken as _};
use lluav_lan9118::regs::*;
use lluav_lan9118::{Buffers, Error, Lan9118, MTU, Signals, Wait};

const MAC: [u8; 6] = [0x02, 0x4c, 0x4c, 0x55, 0x41, 0x56];

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Access {
    Read(Reg, u32),
    Write(Reg, u32),
}

/// A LAN9118 as far as the driver can tell.
#[derive(Default)]
struct Chip {
    log: RefCell<Vec<Access>>,
    /// Values a register reads next, in order; then its `fixed` value.
    script: RefCell<HashMap<Reg, VecDeque<u32>>>,
    fixed: RefCell<HashMap<Reg, u32>>,
    /// MAC registers by index, and the MAC CSR data register.
    mac: RefCell<HashMap<u32, u32>>,
    mac_data: RefCell<u32>,
    /// PHY registers by index.
    phy: RefCell<HashMap<u32, u16>>,
}

impl Chip {
    /// A chip that is present and ready at once, with an empty RX FIFO, an
    /// empty TX FIFO and a PHY that sees a 100 Mbit/s full duplex partner.
    fn new() -> Chip {
        let chip = Chip::default();
        chip.set(Reg::ByteTest, BYTE_TEST_VALUE);
        chip.set(Reg::IdRev, 0x0118_0001);
        chip.set(Reg::PmtCtrl, PMT_CTRL_READY);
        chip.set(Reg::TxFifoInf, 4608);
        chip.phy.borrow_mut().extend([
            (PhyReg::Bsr as u32, 0x782d),
            (PhyReg::Advertise as u32, 0x01e1),
            (PhyReg::Partner as u32, 0x0f71),
        ]);
        chip
    }

    fn set(&self, reg: Reg, value: u32) {
        self.fixed.borrow_mut().insert(reg, value);
    }

    fn script(&self, reg: Reg, values: &[u32]) {
        self.script.borrow_mut().entry(reg).or_default().extend(values);
    }

    fn take_log(&self) -> Vec<Access> {
        std::mem::take(&mut *self.log.borrow_mut())
    }

    fn writes(log: &[Access], reg: Reg) -> Vec<u32> {
        log.iter()
            .filter_map(|a| match *a {
                Access::Write(r, v) if r == reg => Some(v),
                _ => None,
            })
            .collect()
    }

    fn reads(log: &[Access], reg: Reg) -> usize {
        log.iter()
            .filter(|a| matches!(a, Access::Read(r, _) if *r == reg))
            .count()
    }

    fn mac(&self, reg: MacReg) -> u32 {
        self.mac.borrow().get(&(reg as u32)).copied().unwrap_or(0)
    }

    fn phy(&self, reg: PhyReg) -> u16 {
        self.phy.borrow().get(&(reg as u32)).copied().unwrap_or(0)
    }

    /// A MAC CSR command: the indirect access it starts completes at once.
    fn mac_command(&self, value: u32) {
        if value & MAC_CSR_BUSY == 0 {
            return;
        }
        let reg = value & 0xff;
        if value & MAC_CSR_READ != 0 {
            *self.mac_data.borrow_mut() = self.mac.borrow().get(&reg).copied().unwrap_or(0);
            return;
        }
        let data = *self.mac_data.borrow();
        if reg == MacReg::MiiAcc as u32 {
            assert_eq!(data >> 11 & 0x1f, PHY_ADDRESS, "the internal PHY's address");
            let phy_reg = data >> 6 & 0x1f;
            if data & MII_WRITE != 0 {
                let value = self.mac(MacReg::MiiData) as u16;
                self.phy.borrow_mut().insert(phy_reg, value);
            } else {
                let value = self.phy.borrow().get(&phy_reg).copied().unwrap_or(0);
                self.mac
                    .borrow_mut()
                    .insert(MacReg::MiiData as u32, u32::from(value));
            }
            // The access is over: the busy bit reads clear.
            self.mac.borrow_mut().insert(reg, data & !MII_BUSY);
            return;
        }
        self.mac.borrow_mut().insert(reg, data);
    }
}

impl Registers for Chip {
    fn read(&self, reg: Reg) -> u32 {
        let scripted = self
            .script
            .borrow_mut()
            .get_mut(&reg)
            .and_then(VecDeque::pop_front);
        let value = match (scripted, reg) {
            (Some(v), _) => v,
            (None, Reg::MacCsrData) => *self.mac_data.borrow(),
            (None, _) => self.fixed.borrow().get(&reg).copied().unwrap_or(0),
        };
        self.log.borrow_mut().push(Access::Read(reg, value));
        value
    }

    fn write(&self, reg: Reg, value: u32) {
        self.log.borrow_mut().push(Access::Write(reg, value));
        match reg {
            Reg::MacCsrData => *self.mac_data.borrow_mut() = value,
            Reg::MacCsrCmd => self.mac_command(value),
            Reg::IntEn => self.set(Reg::IntEn, value),
            _ => {}
        }
    }
}

/// A waker that records being woken.
#[derive(Default)]
struct Flag(AtomicBool);

impl Wake for Flag {
    fn wake(self: Arc<Self>) {
        self.0.store(true, Ordering::SeqCst);
    }
}

impl Flag {
    fn new() -> (Arc<Flag>, Waker) {
        let flag = Arc::new(Flag::default());
        (flag.clone(), Waker::from(flag))
    }

    fn woken(&self) -> bool {
        self.0.swap(false, Ordering::SeqCst)
    }
}

#[test]
fn reset_comes_first_and_waits_for_the_chip_to_finish_and_be_ready() {
    let chip = Chip::new();
    chip.script(Reg::HwCfg, &[HW_CFG_SRST, HW_CFG_SRST, 0]);
    chip.script(Reg::PmtCtrl, &[0, 0, PMT_CTRL_READY]);
    let (signals, mut buffers) = (Signals::new(), Buffers::new());
    let lan = Lan9118::new(&chip, &signals, &mut buffers, MAC).expect("configured");
    assert_eq!(lan.id_rev() >> 16, 0x0118);
    let log = chip.take_log();
    assert_eq!(
        log.get(..10),
        Some(
            &[
                Access::Read(Reg::ByteTest, BYTE_TEST_VALUE),
                Access::Read(Reg::IdRev, 0x0118_0001),
                Access::Write(Reg::HwCfg, HW_CFG_SRST),
                Access::Read(Reg::HwCfg, HW_CFG_SRST),
                Access::Read(Reg::HwCfg, HW_CFG_SRST),
                Access::Read(Reg::HwCfg, 0),
                Access::Read(Reg::PmtCtrl, 0),
                Access::Read(Reg::PmtCtrl, 0),
                Access::Read(Reg::PmtCtrl, PMT_CTRL_READY),
                // Interrupts stay off until the chip is configured.
                Access::Write(Reg::IntEn, 0),
            ][..]
        )
    );
    // The pin is enabled last, active high and push-pull, for received
    // frames and the PHY only.
    assert_eq!(
        log.get(log.len() - 3..),
        Some(
            &[
                Access::Write(Reg::IntSts, u32::MAX),
                Access::Write(Reg::IntEn, INT_RSFL | INT_PHY),
                Access::Write(Reg::IrqCfg, IRQ_EN | IRQ_POL | IRQ_TYPE),
            ][..]
        )
    );
    assert_eq!(Chip::writes(&log, Reg::RxCfg), [0], "no offset, 4-byte alignment");
    assert_eq!(Chip::writes(&log, Reg::TxCfg), [TX_CFG_TX_ON | TX_CFG_TXSAO]);
    assert_eq!(chip.mac(MacReg::Cr), MAC_CR_TXEN | MAC_CR_RXEN);
}

#[test]
fn a_chip_that_is_not_there_or_never_ends_its_reset_is_refused() {
    let (signals, mut buffers) = (Signals::new(), Buffers::new());
    let absent = Chip::new();
    absent.set(Reg::ByteTest, 0x4321_8765);
    assert_eq!(
        Lan9118::new(&absent, &signals, &mut buffers, MAC).err(),
        Some(Error::NotFound {
            byte_test: 0x4321_8765
        })
    );
    assert!(
        !Chip::writes(&absent.take_log(), Reg::HwCfg).contains(&HW_CFG_SRST),
        "nothing is written to a chip that is not there"
    );
    let stuck = Chip::new();
    stuck.set(Reg::HwCfg, HW_CFG_SRST);
    assert_eq!(
        Lan9118::new(&stuck, &signals, &mut buffers, MAC).err(),
        Some(Error::Timeout(Wait::Reset))
    );
}

#[test]
fn mac_registers_are_written_data_first_then_the_busy_command_once_the_last_is_done() {
    let chip = Chip::new();
    // The first MAC access finds the CSR busy twice.
    chip.script(Reg::MacCsrCmd, &[MAC_CSR_BUSY, MAC_CSR_BUSY]);
    let (signals, mut buffers) = (Signals::new(), Buffers::new());
    Lan9118::new(&chip, &signals, &mut buffers, MAC).expect("configured");
    let log = chip.take_log();
    let first = log
        .iter()
        .position(|a| matches!(a, Access::Read(Reg::MacCsrCmd, _)))
        .expect("a MAC access");
    assert_eq!(
        log.get(first..first + 6),
        Some(
            &[
                Access::Read(Reg::MacCsrCmd, MAC_CSR_BUSY),
                Access::Read(Reg::MacCsrCmd, MAC_CSR_BUSY),
                Access::Read(Reg::MacCsrCmd, 0),
                Access::Write(Reg::MacCsrData, 0x554c_4c02),
                Access::Write(Reg::MacCsrCmd, MAC_CSR_BUSY | MacReg::AddrL as u32),
                Access::Read(Reg::MacCsrCmd, 0),
            ][..]
        )
    );
    assert_eq!(chip.mac(MacReg::AddrL), 0x554c_4c02, "bytes 0-3, little-endian");
    assert_eq!(chip.mac(MacReg::AddrH), 0x5641, "bytes 4-5");
}

#[test]
fn phy_registers_are_reached_through_mii_at_the_internal_phy_address() {
    let chip = Chip::new();
    let (signals, mut buffers) = (Signals::new(), Buffers::new());
    Lan9118::new(&chip, &signals, &mut buffers, MAC).expect("configured");
    assert_eq!(chip.phy(PhyReg::Bcr), BCR_AN_ENABLE | BCR_AN_RESTART);
    assert_eq!(chip.phy(PhyReg::IntMask), PHY_INT_AN_COMPLETE | PHY_INT_LINK_DOWN);
    let log = chip.take_log();
    let commands = Chip::writes(&log, Reg::MacCsrData);
    let bcr = PHY_ADDRESS << 11 | (PhyReg::Bcr as u32) << 6 | MII_WRITE | MII_BUSY;
    let at = commands.iter().position(|&v| v == bcr).expect("the BCR write");
    assert_eq!(
        commands.get(at - 1),
        Some(&u32::from(BCR_AN_ENABLE | BCR_AN_RESTART)),
        "MII data before the MII command"
    );
}

#[test]
fn the_link_is_read_after_a_phy_interrupt_and_sets_the_duplex_both_ends_can_do() {
    let chip = Chip::new();
    let (signals, mut buffers) = (Signals::new(), Buffers::new());
    let mut lan = Lan9118::new(&chip, &signals, &mut buffers, MAC).expect("configured");
    let (flag, waker) = Flag::new();
    let mut cx = Context::from_waker(&waker);
    assert!(lan.link_state(&mut cx) == LinkState::Up);
    assert_eq!(chip.mac(MacReg::Cr), MAC_CR_TXEN | MAC_CR_RXEN | MAC_CR_FDPX);
    chip.take_log();
    // Nothing happened: the cached state, no bus traffic.
    assert!(lan.link_state(&mut cx) == LinkState::Up);
    assert_eq!(chip.take_log(), []);

    // The partner now only does half duplex, then the link drops.
    chip.phy.borrow_mut().insert(PhyReg::Partner as u32, 0x00a1);
    chip.set(Reg::IntSts, INT_PHY);
    signals.on_interrupt(&chip);
    assert!(flag.woken());
    assert_eq!(chip.take_log().last(), Some(&Access::Write(Reg::IntSts, INT_PHY)));
    assert_eq!(
        chip.fixed.borrow()[&Reg::IntEn] & INT_PHY,
        0,
        "masked until the driver has read the PHY"
    );
    assert!(lan.link_state(&mut cx) == LinkState::Up);
    assert_eq!(chip.mac(MacReg::Cr), MAC_CR_TXEN | MAC_CR_RXEN);
    assert_ne!(chip.fixed.borrow()[&Reg::IntEn] & INT_PHY, 0, "unmasked again");

    chip.phy.borrow_mut().insert(PhyReg::Bsr as u32, 0x7809);
    signals.on_interrupt(&chip);
    assert!(lan.link_state(&mut cx) == LinkState::Down);
}

#[test]
fn a_frame_goes_out_as_command_a_command_b_and_little_endian_words() {
    let chip = Chip::new();
    let (signals, mut buffers) = (Signals::new(), Buffers::new());
    let mut lan = Lan9118::new(&chip, &signals, &mut buffers, MAC).expect("configured");
    chip.take_log();
    let frame: Vec<u8> = (0..61).collect();
    let (_, waker) = Flag::new();
    let token = lan.transmit(&mut Context::from_waker(&waker)).expect("room");
    token.consume(frame.len(), |buf| buf.copy_from_slice(&frame));
    let sent = Chip::writes(&chip.take_log(), Reg::TxData);
    assert_eq!(sent.first(), Some(&(TX_CMD_A_FIRST | TX_CMD_A_LAST | 61)));
    assert_eq!(sent.get(1), Some(&61), "command B: the frame's length");
    assert_eq!(sent.len(), 2 + 16, "61 bytes are 16 words");
    assert_eq!(sent.get(2), Some(&0x0302_0100));
    assert_eq!(sent.last(), Some(&0x3c), "the last word carries byte 60, padded");
}

#[test]
fn the_largest_frame_is_sent_whole_and_a_longer_request_is_cut_to_it() {
    let chip = Chip::new();
    let (signals, mut buffers) = (Signals::new(), Buffers::new());
    let mut lan = Lan9118::new(&chip, &signals, &mut buffers, MAC).expect("configured");
    chip.take_log();
    let (_, waker) = Flag::new();
    let token = lan.transmit(&mut Context::from_waker(&waker)).expect("room");
    let given = token.consume(MTU + 100, |buf| buf.len());
    assert_eq!(given, MTU);
    let sent = Chip::writes(&chip.take_log(), Reg::TxData);
    assert_eq!(sent.len(), 2 + MTU.div_ceil(4));
}

#[test]
fn without_room_for_a_frame_the_sender_waits_for_tdfa() {
    let chip = Chip::new();
    let (signals, mut buffers) = (Signals::new(), Buffers::new());
    let mut lan = Lan9118::new(&chip, &signals, &mut buffers, MAC).expect("configured");
    chip.set(Reg::TxFifoInf, 1000);
    let (flag, waker) = Flag::new();
    let mut cx = Context::from_waker(&waker);
    assert!(lan.transmit(&mut cx).is_none());
    assert_ne!(chip.fixed.borrow()[&Reg::IntEn] & INT_TDFA, 0, "TDFA asked for");

    chip.set(Reg::TxFifoInf, 4608);
    chip.set(Reg::IntSts, INT_TDFA);
    chip.take_log();
    signals.on_interrupt(&chip);
    assert!(flag.woken());
    let log = chip.take_log();
    assert_eq!(
        Chip::writes(&log, Reg::IntEn),
        [INT_RSFL | INT_PHY],
        "TDFA masked again"
    );
    assert_eq!(Chip::writes(&log, Reg::IntSts), [INT_TDFA], "and acknowledged");
    assert!(lan.transmit(&mut cx).is_some());
}

/// Scripts `frames` (status word, bytes with their FCS) into the RX FIFOs.
fn receive(chip: &Chip, frames: &[(u32, &[u8])]) {
    let mut infos: Vec<u32> = (1..=frames.len() as u32).rev().map(|n| n << 16).collect();
    infos.push(0);
    chip.script(Reg::RxFifoInf, &infos);
    for (status, bytes) in frames {
        chip.script(Reg::RxStatus, &[*status]);
        let words: Vec<u32> = bytes
            .chunks(4)
            .map(|c| c.iter().rev().fold(0, |w, &b| w << 8 | u32::from(b)))
            .collect();
        chip.script(Reg::RxData, &words);
    }
}

fn status(length: usize) -> u32 {
    (length as u32) << 16
}

#[test]
fn a_received_frame_is_its_status_then_its_words_without_the_fcs() {
    let chip = Chip::new();
    let (signals, mut buffers) = (Signals::new(), Buffers::new());
    let mut lan = Lan9118::new(&chip, &signals, &mut buffers, MAC).expect("configured");
    chip.take_log();
    let frame: Vec<u8> = (0..66).map(|i| i as u8 ^ 0x5a).collect();
    let with_fcs = [&frame[..], &[0xde, 0xad, 0xbe, 0xef]].concat();
    receive(&chip, &[(status(with_fcs.len()), &with_fcs)]);
    let (_, waker) = Flag::new();
    let (rx, _tx) = lan.receive(&mut Context::from_waker(&waker)).expect("a frame");
    assert_eq!(rx.consume(|got| got.to_vec()), frame);
    let log = chip.take_log();
    assert_eq!(
        log.get(..2),
        Some(
            &[
                Access::Read(Reg::RxFifoInf, 1 << 16),
                Access::Read(Reg::RxStatus, status(70))
            ][..]
        )
    );
    assert_eq!(
        Chip::reads(&log, Reg::RxData),
        70_usize.div_ceil(4),
        "every word of it"
    );
}

#[test]
fn a_frame_with_an_error_is_read_out_dropped_and_the_next_one_taken() {
    let chip = Chip::new();
    let (signals, mut buffers) = (Signals::new(), Buffers::new());
    let mut lan = Lan9118::new(&chip, &signals, &mut buffers, MAC).expect("configured");
    chip.take_log();
    let bad = [0xffu8; 64];
    let good: Vec<u8> = (0..64).collect();
    let oversized = vec![0u8; 2000];
    receive(
        &chip,
        &[
            (status(bad.len()) | RX_STATUS_ERROR, &bad),
            (status(oversized.len()), &oversized),
            (status(good.len()), &good),
        ],
    );
    let (_, waker) = Flag::new();
    let (rx, _tx) = lan.receive(&mut Context::from_waker(&waker)).expect("a frame");
    assert_eq!(rx.consume(|got| got.to_vec()), good[..60]);
    assert_eq!(lan.dropped(), 2);
    let log = chip.take_log();
    assert_eq!(
        Chip::reads(&log, Reg::RxData),
        16 + 500 + 16,
        "the dropped ones too"
    );
}

#[test]
fn with_nothing_received_the_receiver_waits_for_rsfl_which_is_only_acknowledged() {
    let chip = Chip::new();
    let (signals, mut buffers) = (Signals::new(), Buffers::new());
    let mut lan = Lan9118::new(&chip, &signals, &mut buffers, MAC).expect("configured");
    let (flag, waker) = Flag::new();
    assert!(lan.receive(&mut Context::from_waker(&waker)).is_none());
    chip.take_log();
    chip.set(Reg::IntSts, INT_RSFL);
    signals.on_interrupt(&chip);
    assert!(flag.woken());
    let log = chip.take_log();
    assert_eq!(Chip::writes(&log, Reg::IntSts), [INT_RSFL]);
    assert_eq!(Chip::writes(&log, Reg::IntEn), [], "RSFL stays enabled");
}

#[test]
fn an_interrupt_source_that_is_not_enabled_wakes_nobody() {
    let chip = Chip::new();
    let (signals, mut buffers) = (Signals::new(), Buffers::new());
    let mut lan = Lan9118::new(&chip, &signals, &mut buffers, MAC).expect("configured");
    let (flag, waker) = Flag::new();
    assert!(lan.transmit(&mut Context::from_waker(&waker)).is_some());
    chip.set(Reg::IntSts, INT_TDFA);
    signals.on_interrupt(&chip);
    assert!(!flag.woken());
}
