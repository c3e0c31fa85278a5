//! Spec §2.5 and extensions §1 on the 8318's acquisition task (`remodaq_8318::acquisition::run`),
//! on a mock clock this test moves 1 ms at a time:
//! - one cycle every 100 ms: ten cycles in the first 1050 ms, 100 ms apart;
//! - module status bit 5 (inputs not valid yet) is set until the first cycle is published;
//! - a reader never sees half a cycle: the front end takes 5 ms a channel, every channel reads
//!   k mV in cycle k, and every read of the 8 values (one request) in between shows one k.

use std::cell::{Cell, RefCell};
use std::future::Future;
use std::pin::pin;
use std::task::{Context, Poll, Waker};

use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, NoopRawMutex};
use embassy_sync::mutex::Mutex;
use embassy_time::{Duration, Instant, MockDriver, Timer};
use remodaq_8318::acquisition::{run, AnalogFrontEnd, Measurement};
use remodaq_8318::map::Map8318;
use remodaq_8318::settings::Settings;
use remodaq_shared::modbus::{handle_pdu, MAX_PDU};
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::SettingsStore;

type Flash = RamFlash<{ 4 * 1024 }, 1024>;

/// Every channel reads `cycle` mV in the cycle it is in; each conversion takes 5 ms.
struct Slow<'a> {
    cycle: &'a Cell<u32>,
    measured: &'a Cell<u32>,
}

impl AnalogFrontEnd for Slow<'_> {
    type Error = &'static str;
    async fn measure(&mut self, channel: u8, _: f64, _: bool) -> Result<Measurement, Self::Error> {
        if channel == 0 {
            self.cycle.set(self.cycle.get() + 1);
        }
        self.measured.set(self.measured.get() + 1);
        Timer::after_millis(5).await;
        Ok(Measurement::Millivolts(f64::from(self.cycle.get())))
    }
    async fn cold_junction_c(&mut self) -> Result<f64, Self::Error> {
        Ok(25.0)
    }
}

/// Polls `f` once (the map's lock is never held across a wait here, so a read completes).
fn now_or_never<F: Future>(f: F) -> Option<F::Output> {
    let mut f = pin!(f);
    match f.as_mut().poll(&mut Context::from_waker(Waker::noop())) {
        Poll::Ready(v) => Some(v),
        Poll::Pending => None,
    }
}

#[test]
fn ten_cycles_a_second_whole_cycles_and_bit_5_until_the_first() {
    let clock = MockDriver::get();
    clock.reset();
    let start = Instant::now();
    let store = now_or_never(SettingsStore::<Flash, Settings>::open(
        Flash::new(),
        const { SettingsStore::<Flash, Settings>::config(0..4096) },
    ))
    .expect("a RAM store opens at once");
    let settings = Settings { input_type: 0x02, ..*store.get() }; // ±100 mV
    let store = Mutex::<CriticalSectionRawMutex, _>::new(store);
    let map = Mutex::<NoopRawMutex, _>::new(Map8318::new(&store, &settings));
    let cycle = Cell::new(0);
    let ends = RefCell::new(Vec::new());
    let measured = Cell::new(0);
    let mut fe = Slow { cycle: &cycle, measured: &measured };
    let mut task = pin!(run(&mut fe, &map, || ends.borrow_mut().push(start.elapsed().as_millis())));
    let mut cx = Context::from_waker(Waker::noop());
    let read = |pdu: &[u8]| {
        let mut resp = [0u8; MAX_PDU];
        let n = now_or_never(handle_pdu(&map, [127, 0, 0, 1], pdu, &mut resp)).expect("the map is free");
        resp[..n].to_vec()
    };
    let mut seen = std::collections::BTreeSet::new();
    for ms in 0..=1050 {
        assert!(task.as_mut().poll(&mut cx).is_pending());
        let status = read(&[0x03, 0x00, 0xF0, 0x00, 0x01]);
        let pending = status[3] & 0x20 != 0;
        assert_eq!(pending, ends.borrow().is_empty(), "bit 5 at {ms} ms: {status:02x?}");
        // Values 40001-40008 in one request: all from one cycle.
        let values = read(&[0x03, 0x00, 0x00, 0x00, 0x08]);
        let raws: Vec<u16> = values[2..].chunks(2).map(|w| u16::from_be_bytes([w[0], w[1]])).collect();
        assert!(raws.iter().all(|r| *r == raws[0]), "{ms} ms: {raws:04x?}: half a cycle");
        seen.insert(raws[0]);
        clock.advance(Duration::from_millis(1));
    }
    // Spec §2.5: one cycle every 100 ms. Ten cycles in the first 1050 ms, each 100 ms after
    // the one before (the first within the first period).
    let ends = ends.borrow();
    assert_eq!(ends.len(), 10, "ten cycles: {ends:?}");
    assert!(ends[0] <= 100 + 8 * 5, "the first cycle within the first period: {ends:?}");
    assert!(ends.windows(2).all(|w| w[1] - w[0] == 100), "one cycle a 100 ms: {ends:?}");
    assert_eq!(measured.get(), 80, "8 channels a cycle");
    // Before the first cycle 0000h; then k mV on ±100 mV: round((k + 100) / 200 * 65535).
    let expected: std::collections::BTreeSet<u16> = std::iter::once(0)
        .chain((1..=10).map(|k: u32| ((f64::from(k) + 100.0) / 200.0 * 65535.0).round() as u16))
        .collect();
    assert_eq!(seen, expected);
}
