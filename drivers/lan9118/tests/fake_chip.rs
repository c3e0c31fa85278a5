//! The driver's register sequences against a fake LAN9118 register block.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context, Wake, Waker};

use embassy_net_driver::{Driver, HardwareAddress, RxToken as _, TxToken as _};
use remodaq_lan9118::{on_interrupt, reg, InitError, Lan9118, Registers, INT_RSFL};

/// The driver's receive waker is one static (the interrupt handler's), so tests that register
/// wakers or raise the interrupt run one at a time.
fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

#[derive(Default)]
struct State {
    byte_test: u32,
    hw_cfg: u32,
    reset_polls: u32,
    mac_csr_data: u32,
    mac: [u32; 16],
    int_sts: u32,
    writes: Vec<(usize, u32)>,
    rx_frames: VecDeque<(Vec<u8>, bool)>,
    rx_words: VecDeque<u32>,
    tx_words: Vec<u32>,
    sent: Vec<Vec<u8>>,
}

#[derive(Clone, Copy)]
struct Fake<'a>(&'a RefCell<State>);

impl Registers for Fake<'_> {
    fn read(&self, offset: usize) -> u32 {
        let mut s = self.0.borrow_mut();
        match offset {
            reg::BYTE_TEST => s.byte_test,
            reg::HW_CFG => {
                if s.reset_polls > 0 {
                    s.reset_polls -= 1;
                } else {
                    s.hw_cfg &= !1;
                }
                s.hw_cfg
            }
            reg::PMT_CTRL => 1,
            reg::MAC_CSR_CMD => 0,
            reg::MAC_CSR_DATA => s.mac_csr_data,
            reg::INT_STS => s.int_sts,
            reg::RX_FIFO_INF => (s.rx_frames.len() as u32) << 16,
            reg::RX_STATUS_FIFO => {
                let (frame, error) = s.rx_frames.pop_front().expect("status FIFO read when empty");
                // QEMU appends 4 CRC bytes and counts them in the length.
                let mut bytes = frame.clone();
                bytes.extend_from_slice(&[0xC1, 0xC2, 0xC3, 0xC4]);
                let len = bytes.len() as u32;
                for chunk in bytes.chunks(4) {
                    let mut w = [0u8; 4];
                    w[..chunk.len()].copy_from_slice(chunk);
                    s.rx_words.push_back(u32::from_le_bytes(w));
                }
                len << 16 | if error { 1 << 15 } else { 0 }
            }
            reg::RX_DATA_FIFO => s.rx_words.pop_front().expect("data FIFO read past the frame"),
            _ => 0,
        }
    }

    fn write(&self, offset: usize, value: u32) {
        let mut s = self.0.borrow_mut();
        s.writes.push((offset, value));
        match offset {
            reg::HW_CFG => s.hw_cfg = value,
            reg::MAC_CSR_DATA => s.mac_csr_data = value,
            reg::MAC_CSR_CMD => {
                let index = (value & 0xFF) as usize;
                if value & (1 << 30) != 0 {
                    s.mac_csr_data = s.mac[index];
                } else {
                    s.mac[index] = s.mac_csr_data;
                }
            }
            reg::INT_STS => s.int_sts &= !value,
            reg::TX_DATA_FIFO => {
                s.tx_words.push(value);
                let a = s.tx_words[0];
                let len = (a & 0x7FF) as usize;
                if s.tx_words.len() == 2 + len.div_ceil(4) {
                    let mut bytes: Vec<u8> = s.tx_words[2..].iter().flat_map(|w| w.to_le_bytes()).collect();
                    bytes.truncate(len);
                    assert_eq!(s.tx_words[1] & 0x7FF, len as u32, "command B length");
                    assert_eq!(a & (3 << 12), 3 << 12, "first and last segment");
                    s.sent.push(bytes);
                    s.tx_words.clear();
                }
            }
            _ => {}
        }
    }
}

const MAC: [u8; 6] = [0x02, 0x00, 0x5E, 0x10, 0x20, 0x30];

fn chip() -> RefCell<State> {
    RefCell::new(State { byte_test: 0x8765_4321, reset_polls: 3, ..State::default() })
}

struct Count(AtomicUsize);
impl Wake for Count {
    fn wake(self: Arc<Self>) {
        self.0.fetch_add(1, Ordering::SeqCst);
    }
}

#[test]
fn init_checks_byte_order_resets_and_configures() {
    let _serial = serial();
    let bad = RefCell::new(State { byte_test: 0x4321_8765, ..State::default() });
    assert_eq!(Lan9118::new(Fake(&bad), MAC).err(), Some(InitError::ByteTest(0x4321_8765)));
    let stuck = RefCell::new(State { byte_test: 0x8765_4321, reset_polls: u32::MAX, ..State::default() });
    assert_eq!(Lan9118::new(Fake(&stuck), MAC).err(), Some(InitError::Timeout));

    let state = chip();
    let driver = Lan9118::new(Fake(&state), MAC).unwrap();
    let s = state.borrow();
    assert_eq!(s.writes[0], (reg::HW_CFG, 1), "soft reset first");
    assert_eq!(s.mac[3], 0x105E_0002, "ADDRL = bytes 0..3, little-endian");
    assert_eq!(s.mac[2], 0x3020, "ADDRH = bytes 4, 5");
    assert_eq!(s.mac[1] & 0b1100, 0b1100, "MAC_CR: TXEN and RXEN");
    assert!(s.writes.contains(&(reg::TX_CFG, 0b110)), "TX on, status overrun allowed");
    assert!(s.writes.contains(&(reg::INT_EN, INT_RSFL)));
    assert_eq!(s.writes.last(), Some(&(reg::IRQ_CFG, 1 << 8 | 1 << 4 | 1)), "interrupts enabled last");
    drop(s);
    assert_eq!(driver.hardware_address(), HardwareAddress::Ethernet(MAC));
    assert_eq!(driver.mac_read(2).unwrap(), 0x3020);
}

#[test]
fn receives_frames_of_any_length_and_drops_bad_ones() {
    let _serial = serial();
    let state = chip();
    let mut driver = Lan9118::new(Fake(&state), MAC).unwrap();
    let waker = Waker::from(Arc::new(Count(AtomicUsize::new(0))));
    let mut cx = Context::from_waker(&waker);
    assert!(driver.receive(&mut cx).is_none(), "nothing yet");
    let frame: Vec<u8> = (0..61).collect();
    state.borrow_mut().rx_frames.push_back((vec![0xEE; 64], true));
    state.borrow_mut().rx_frames.push_back((frame.clone(), false));
    state.borrow_mut().rx_frames.push_back((vec![7; 1514], false));
    let (rx, _tx) = driver.receive(&mut cx).expect("a frame");
    assert_eq!(rx.consume(|b| b.to_vec()), frame, "CRC removed, odd length kept");
    let (rx, _tx) = driver.receive(&mut cx).expect("a full-size frame");
    assert_eq!(rx.consume(|b| b.len()), 1514);
    assert!(driver.receive(&mut cx).is_none());
    assert_eq!(driver.rx_dropped, 1, "the frame with an error status");
    assert!(state.borrow().rx_words.is_empty(), "every word of every frame consumed");
}

#[test]
fn transmits_through_the_tx_fifo() {
    let _serial = serial();
    let state = chip();
    let mut driver = Lan9118::new(Fake(&state), MAC).unwrap();
    let waker = Waker::from(Arc::new(Count(AtomicUsize::new(0))));
    let mut cx = Context::from_waker(&waker);
    for len in [42usize, 43, 60, 1514] {
        let tx = driver.transmit(&mut cx).unwrap();
        tx.consume(len, |b| b.iter_mut().enumerate().for_each(|(i, x)| *x = i as u8));
    }
    let sent = &state.borrow().sent;
    assert_eq!(sent.iter().map(Vec::len).collect::<Vec<_>>(), vec![42, 43, 60, 1514]);
    assert!(sent[1].iter().enumerate().all(|(i, b)| *b == i as u8));
}

#[test]
fn interrupt_clears_status_and_wakes_the_stack() {
    let _serial = serial();
    let state = chip();
    let mut driver = Lan9118::new(Fake(&state), MAC).unwrap();
    let count = Arc::new(Count(AtomicUsize::new(0)));
    let waker = Waker::from(count.clone());
    let mut cx = Context::from_waker(&waker);
    assert!(driver.receive(&mut cx).is_none(), "registers the waker");
    state.borrow_mut().int_sts = INT_RSFL | 1 << 31;
    on_interrupt(Fake(&state));
    assert_eq!(state.borrow().int_sts, 0, "write-1-to-clear of what was set");
    assert_eq!(count.0.load(Ordering::SeqCst), 1);
}
