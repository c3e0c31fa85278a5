//! An embassy-net driver for the SMSC LAN9118 Ethernet controller, as QEMU emulates it on the
//! mps2 boards (`-nic model=lan9118`).
//!
//! The chip is reached through [`Registers`] (32-bit reads and writes at byte offsets), so the
//! register sequences run on the host against a fake register block. Receive is interrupt
//! driven: the board's interrupt handler calls [`on_interrupt`], which clears the chip's
//! interrupt status and wakes the network stack, which then drains the RX FIFOs.
#![no_std]
#![warn(missing_docs)]

use core::task::Context;

use embassy_net_driver::{Capabilities, Driver, HardwareAddress, LinkState};
use embassy_sync::waitqueue::AtomicWaker;

/// Register offsets (SMSC LAN9118 datasheet, system control and status registers).
pub mod reg {
    /// RX data FIFO port.
    pub const RX_DATA_FIFO: usize = 0x00;
    /// TX data FIFO port.
    pub const TX_DATA_FIFO: usize = 0x20;
    /// RX status FIFO port.
    pub const RX_STATUS_FIFO: usize = 0x40;
    /// TX status FIFO port.
    pub const TX_STATUS_FIFO: usize = 0x48;
    /// Chip id and revision.
    pub const ID_REV: usize = 0x50;
    /// Interrupt configuration.
    pub const IRQ_CFG: usize = 0x54;
    /// Interrupt status (write 1 to clear).
    pub const INT_STS: usize = 0x58;
    /// Interrupt enable.
    pub const INT_EN: usize = 0x5C;
    /// Byte order test: reads 0x87654321.
    pub const BYTE_TEST: usize = 0x64;
    /// FIFO level interrupts.
    pub const FIFO_INT: usize = 0x68;
    /// Receive configuration.
    pub const RX_CFG: usize = 0x6C;
    /// Transmit configuration.
    pub const TX_CFG: usize = 0x70;
    /// Hardware configuration.
    pub const HW_CFG: usize = 0x74;
    /// RX FIFO information.
    pub const RX_FIFO_INF: usize = 0x7C;
    /// TX FIFO information.
    pub const TX_FIFO_INF: usize = 0x80;
    /// Power management control (READY bit).
    pub const PMT_CTRL: usize = 0x84;
    /// MAC CSR command.
    pub const MAC_CSR_CMD: usize = 0xA4;
    /// MAC CSR data.
    pub const MAC_CSR_DATA: usize = 0xA8;

    /// MAC registers, reached through MAC_CSR_CMD / MAC_CSR_DATA.
    pub mod mac {
        /// MAC control.
        pub const MAC_CR: u32 = 1;
        /// Address high (bytes 4, 5).
        pub const ADDRH: u32 = 2;
        /// Address low (bytes 0..3).
        pub const ADDRL: u32 = 3;
    }
}

/// BYTE_TEST's value.
pub const BYTE_TEST_VALUE: u32 = 0x8765_4321;
const HW_CFG_SRST: u32 = 1 << 0;
const PMT_READY: u32 = 1 << 0;
const CSR_BUSY: u32 = 1 << 31;
const CSR_READ: u32 = 1 << 30;
const MAC_CR_RXEN: u32 = 1 << 2;
const MAC_CR_TXEN: u32 = 1 << 3;
const MAC_CR_FDPX: u32 = 1 << 20;
const TX_CFG_TX_ON: u32 = 1 << 1;
const TX_CFG_TXSAO: u32 = 1 << 2;
/// INT_STS / INT_EN: RX status FIFO level.
pub const INT_RSFL: u32 = 1 << 3;
const IRQ_CFG_TYPE_PUSH_PULL: u32 = 1 << 0;
const IRQ_CFG_POL_HIGH: u32 = 1 << 4;
const IRQ_CFG_EN: u32 = 1 << 8;
const RX_STATUS_ERROR: u32 = 1 << 15;
const TX_CMD_A_FIRST: u32 = 1 << 13;
const TX_CMD_A_LAST: u32 = 1 << 12;

/// Largest frame handled (with the 4 CRC bytes the chip appends on receive).
pub const MAX_FRAME: usize = 1536;
const WORDS: usize = MAX_FRAME / 4;
/// Bounded polls of the chip's busy / ready bits.
const POLLS: u32 = 100_000;

/// 32-bit access to the chip's registers.
pub trait Registers: Copy {
    /// Reads the register at byte `offset`.
    fn read(&self, offset: usize) -> u32;
    /// Writes the register at byte `offset`.
    fn write(&self, offset: usize, value: u32);
}

/// Why the chip could not be brought up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InitError {
    /// BYTE_TEST did not read 0x87654321: no chip, or wrong bus width / byte order.
    ByteTest(u32),
    /// The chip did not come out of reset, or a MAC CSR access stayed busy.
    Timeout,
}

/// Woken by [`on_interrupt`]; the driver registers the stack's waker here.
pub static RX_WAKER: AtomicWaker = AtomicWaker::new();

/// The interrupt handler's work: clear the chip's interrupt status and wake the stack.
pub fn on_interrupt<R: Registers>(regs: R) {
    let status = regs.read(reg::INT_STS);
    regs.write(reg::INT_STS, status);
    RX_WAKER.wake();
}

/// The driver.
pub struct Lan9118<R: Registers> {
    regs: R,
    mac: [u8; 6],
    rx: [u32; WORDS],
    tx: [u32; WORDS],
    /// Frames received and dropped (receive errors, too long).
    pub rx_dropped: u32,
    /// The link is reported down whatever the chip says ([`Lan9118::hold_link_down`]).
    link_held_down: bool,
}

/// Reads a MAC register through MAC_CSR.
fn csr_read<R: Registers>(regs: R, index: u32) -> Result<u32, InitError> {
    regs.write(reg::MAC_CSR_CMD, CSR_BUSY | CSR_READ | index);
    wait_until(|| regs.read(reg::MAC_CSR_CMD) & CSR_BUSY == 0)?;
    Ok(regs.read(reg::MAC_CSR_DATA))
}

/// The MAC address the chip holds before the driver sets one (loaded from its EEPROM at reset;
/// under QEMU, the `-nic ...,mac=` address), if the chip answers and it is a usable unicast
/// address (not all zeros, not a group address).
pub fn stored_mac<R: Registers>(regs: R) -> Option<[u8; 6]> {
    if regs.read(reg::BYTE_TEST) != BYTE_TEST_VALUE {
        return None;
    }
    let low = csr_read(regs, reg::mac::ADDRL).ok()?.to_le_bytes();
    let high = csr_read(regs, reg::mac::ADDRH).ok()?.to_le_bytes();
    let mac = [low[0], low[1], low[2], low[3], high[0], high[1]];
    (mac != [0; 6] && mac[0] & 1 == 0).then_some(mac)
}

fn wait_until(mut done: impl FnMut() -> bool) -> Result<(), InitError> {
    for _ in 0..POLLS {
        if done() {
            return Ok(());
        }
    }
    Err(InitError::Timeout)
}

impl<R: Registers> Lan9118<R> {
    /// Resets the chip, sets its MAC address, enables receive and transmit and the RX
    /// interrupt.
    pub fn new(regs: R, mac: [u8; 6]) -> Result<Self, InitError> {
        let test = regs.read(reg::BYTE_TEST);
        if test != BYTE_TEST_VALUE {
            return Err(InitError::ByteTest(test));
        }
        regs.write(reg::HW_CFG, HW_CFG_SRST);
        wait_until(|| regs.read(reg::HW_CFG) & HW_CFG_SRST == 0)?;
        wait_until(|| regs.read(reg::PMT_CTRL) & PMT_READY != 0)?;
        let chip = Self { regs, mac, rx: [0; WORDS], tx: [0; WORDS], rx_dropped: 0, link_held_down: false };
        chip.mac_write(reg::mac::ADDRL, u32::from_le_bytes([mac[0], mac[1], mac[2], mac[3]]))?;
        chip.mac_write(reg::mac::ADDRH, u32::from(mac[4]) | u32::from(mac[5]) << 8)?;
        chip.mac_write(reg::mac::MAC_CR, MAC_CR_TXEN | MAC_CR_RXEN | MAC_CR_FDPX)?;
        regs.write(reg::TX_CFG, TX_CFG_TX_ON | TX_CFG_TXSAO);
        regs.write(reg::FIFO_INT, 0);
        regs.write(reg::INT_STS, u32::MAX);
        regs.write(reg::INT_EN, INT_RSFL);
        regs.write(reg::IRQ_CFG, IRQ_CFG_EN | IRQ_CFG_POL_HIGH | IRQ_CFG_TYPE_PUSH_PULL);
        Ok(chip)
    }

    /// From now on the link is reported down (test images: a NIC whose link never comes up,
    /// which the firmware's self-test must see).
    pub fn hold_link_down(&mut self) {
        self.link_held_down = true;
    }

    /// Writes a MAC register through MAC_CSR.
    pub fn mac_write(&self, index: u32, value: u32) -> Result<(), InitError> {
        self.regs.write(reg::MAC_CSR_DATA, value);
        self.regs.write(reg::MAC_CSR_CMD, CSR_BUSY | index);
        wait_until(|| self.regs.read(reg::MAC_CSR_CMD) & CSR_BUSY == 0)
    }

    /// Reads a MAC register through MAC_CSR.
    pub fn mac_read(&self, index: u32) -> Result<u32, InitError> {
        csr_read(self.regs, index)
    }

    /// Pops received frames until one is good; its length (CRC removed) stays in `rx`.
    fn poll_rx(&mut self) -> Option<usize> {
        while (self.regs.read(reg::RX_FIFO_INF) >> 16) & 0xFF != 0 {
            let status = self.regs.read(reg::RX_STATUS_FIFO);
            let len = ((status >> 16) & 0x3FFF) as usize;
            let words = len.div_ceil(4);
            if status & RX_STATUS_ERROR != 0 || len < 4 || words > WORDS {
                for _ in 0..words {
                    let _ = self.regs.read(reg::RX_DATA_FIFO);
                }
                self.rx_dropped = self.rx_dropped.wrapping_add(1);
                continue;
            }
            for w in &mut self.rx[..words] {
                *w = self.regs.read(reg::RX_DATA_FIFO);
            }
            return Some(len - 4);
        }
        None
    }

    /// Queues one frame for transmission.
    fn send(regs: R, tx: &mut [u32; WORDS], len: usize) {
        let len = len.min(MAX_FRAME - 4);
        regs.write(reg::TX_DATA_FIFO, TX_CMD_A_FIRST | TX_CMD_A_LAST | len as u32);
        regs.write(reg::TX_DATA_FIFO, (len as u32) << 16 | len as u32);
        for w in &tx[..len.div_ceil(4)] {
            regs.write(reg::TX_DATA_FIFO, *w);
        }
    }
}

fn bytes(words: &mut [u32; WORDS]) -> &mut [u8] {
    // Frames are handled as bytes in the order the FIFO delivers them (little-endian words).
    let (_, bytes, _) = unsafe {
        // SAFETY: u32 has no padding and any byte pattern is a valid u8; the slice covers
        // exactly the array's bytes.
        words.align_to_mut::<u8>()
    };
    bytes
}

/// A received frame.
pub struct RxToken<'a> {
    frame: &'a mut [u8],
}

impl embassy_net_driver::RxToken for RxToken<'_> {
    fn consume<T, F: FnOnce(&mut [u8]) -> T>(self, f: F) -> T {
        f(self.frame)
    }
}

/// Room for one frame to transmit.
pub struct TxToken<'a, R: Registers> {
    regs: R,
    buf: &'a mut [u32; WORDS],
}

impl<R: Registers> embassy_net_driver::TxToken for TxToken<'_, R> {
    fn consume<T, F: FnOnce(&mut [u8]) -> T>(self, len: usize, f: F) -> T {
        let len = len.min(MAX_FRAME - 4);
        let result = f(&mut bytes(self.buf)[..len]);
        Lan9118::send(self.regs, self.buf, len);
        result
    }
}

impl<R: Registers> Driver for Lan9118<R> {
    type RxToken<'a>
        = RxToken<'a>
    where
        Self: 'a;
    type TxToken<'a>
        = TxToken<'a, R>
    where
        Self: 'a;

    fn receive(&mut self, cx: &mut Context) -> Option<(Self::RxToken<'_>, Self::TxToken<'_>)> {
        // Register first: a frame arriving after the poll then wakes the stack.
        RX_WAKER.register(cx.waker());
        let len = self.poll_rx()?;
        let regs = self.regs;
        Some((RxToken { frame: &mut bytes(&mut self.rx)[..len] }, TxToken { regs, buf: &mut self.tx }))
    }

    fn transmit(&mut self, _cx: &mut Context) -> Option<Self::TxToken<'_>> {
        // QEMU's TX FIFO drains at once; on silicon this would check TX_FIFO_INF's free space.
        Some(TxToken { regs: self.regs, buf: &mut self.tx })
    }

    /// Up: QEMU's LAN9118 has its link up from reset (its PHY's status is not read here),
    /// unless held down.
    fn link_state(&mut self, _cx: &mut Context) -> LinkState {
        if self.link_held_down {
            LinkState::Down
        } else {
            LinkState::Up
        }
    }

    fn capabilities(&self) -> Capabilities {
        let mut caps = Capabilities::default();
        caps.max_transmission_unit = 1514;
        caps.max_burst_size = Some(1);
        caps
    }

    fn hardware_address(&self) -> HardwareAddress {
        HardwareAddress::Ethernet(self.mac)
    }
}
