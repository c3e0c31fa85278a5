//! The 8350's I/O loop (`io::run`) over fake board paths: everything the capture hands over
//! reaches the DI engine, a lost batch is survived, and the output pattern is refilled chunk by
//! chunk from the pulse engine.

use std::cell::{Cell, RefCell};
use std::collections::VecDeque;
use std::rc::Rc;

use embassy_futures::select::{select, Either};
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_time::{Duration, Timer};
use futures_executor::block_on;
use remodaq_8350::di::{DiMode, SAMPLE_RATE_HZ};
use remodaq_8350::io::{self, InputCapture, Io, IoCell, OutputPattern, PatternUnderrun, SamplesLost, OUTPUT_CHUNK};
use remodaq_8350::pulse::{DoMode, PulseConfig};
use remodaq_8350::settings::Settings;
use remodaq_shared::settings::Schema;

/// A capture that hands over prepared batches, one per read (`Err` = samples lost), then
/// nothing.
struct FakeCapture(VecDeque<Result<Vec<u16>, SamplesLost>>);

impl InputCapture for FakeCapture {
    fn read(&mut self, out: &mut [u16]) -> Result<usize, SamplesLost> {
        match self.0.pop_front() {
            None => Ok(0),
            Some(Err(lost)) => Err(lost),
            Some(Ok(batch)) => {
                assert!(batch.len() <= out.len(), "the loop reads up to its batch size");
                out[..batch.len()].copy_from_slice(&batch);
                Ok(batch.len())
            }
        }
    }
}

/// A pattern that records what it is given and takes at most `room` chunks.
struct FakePattern {
    written: Rc<RefCell<Vec<Vec<u8>>>>,
    room: usize,
}

impl OutputPattern for FakePattern {
    async fn room(&mut self) {
        if self.written.borrow().len() >= self.room {
            // The ring is full: wait as the hardware would (longer than the test runs).
            Timer::after(Duration::from_secs(3600)).await;
        }
    }

    fn write(&mut self, ticks: &[u8]) -> Result<u32, PatternUnderrun> {
        self.written.borrow_mut().push(ticks.to_vec());
        Ok(0)
    }

    fn force(&mut self, _: u8, _: u8) -> u32 {
        0
    }
}

/// A 50 % square wave on DI0 with `edges` rising edges, 10 samples a period, starting low.
fn square(edges: usize) -> Vec<u16> {
    (0..edges * 10).map(|i| u16::from(i % 10 >= 5)).collect()
}

#[test]
fn every_captured_sample_reaches_the_engine_and_the_pattern_is_refilled() {
    let mut settings = Settings::defaults();
    settings.di_modes[0] = DiMode::Counter;
    settings.do_modes[0] = DoMode::Pulse;
    settings.pulses[0] = PulseConfig { low: 2, high: 3, count: 0 };
    let cell: IoCell<NoopRawMutex> = IoCell::new(RefCell::new(Io::new(SAMPLE_RATE_HZ, &settings)));
    io::with(&cell, |s| {
        s.di.set_run(0, true);
        s.pulse.set_do(0, true);
    });

    // 3 batches of 20, 24 and 25 rising edges (the last one almost a whole read: 250 of
    // DRAIN_BATCH's 256 samples), with a lost batch between the first two.
    let batches = VecDeque::from([Ok(square(20)), Err(SamplesLost), Ok(square(24)), Ok(square(25))]);
    let written = Rc::new(RefCell::new(Vec::new()));
    let pattern = FakePattern { written: written.clone(), room: 3 };
    let beats = Cell::new(0u32);
    let run = io::run(FakeCapture(batches), pattern, &cell, || beats.set(beats.get() + 1));
    // Until every batch is counted, the ring is full and the loop has beaten 10 times (a
    // condition, not a time: a loaded
    // machine may run the 2 ms passes late), at most 10 s.
    let done = async {
        let deadline = embassy_time::Instant::now() + Duration::from_secs(10);
        while (io::with(&cell, |s| s.di.counter_value(0)) < 69 || written.borrow().len() < 3 || beats.get() < 10)
            && embassy_time::Instant::now() < deadline
        {
            Timer::after(Duration::from_millis(2)).await;
        }
    };
    let ended = block_on(select(run, done));
    assert!(matches!(ended, Either::Second(())), "the loop runs forever");

    // 20 + 24 + 25 rising edges, whatever the batches and the lost one between them.
    assert_eq!(io::with(&cell, |s| s.di.counter_value(0)), 69);
    assert!(beats.get() >= 10, "a heartbeat every pass, idle passes too: {}", beats.get());
    // Three chunks were taken (the ring's room), each a whole chunk of the 5-tick train:
    // high 3 ticks, low 2.
    let written = written.borrow();
    assert_eq!(written.len(), 3);
    let ticks: Vec<u8> = written.iter().flatten().copied().collect();
    assert!(written.iter().all(|c| c.len() == OUTPUT_CHUNK));
    for (i, level) in ticks.iter().enumerate() {
        assert_eq!(*level & 1, u8::from(i % 5 < 3), "tick {i}");
    }
}

/// The QEMU board's simulated capture has the STM32's ring: samples left undrained longer than
/// the ring lasts are lost and reported, as the DMA ring's overrun is; drained in time, none
/// are. (A 100-sample ring lasts 2 ms at 50 kHz.)
#[test]
fn a_simulated_ring_overruns_when_drained_late() {
    use remodaq_8350::io::SimulatedCapture;
    let mut capture = SimulatedCapture::with_ring(|_| Some(1u16), 100);
    let mut out = [0u16; 512];
    std::thread::sleep(std::time::Duration::from_millis(20));
    assert_eq!(capture.read(&mut out), Err(SamplesLost), "1000 samples due, a ring of 100");
    // Drained again at once: what came since, nothing lost.
    assert!(capture.read(&mut out).is_ok());
    // Without a ring (the host simulator), never lost.
    let mut unbounded = SimulatedCapture::new(|_| Some(1u16));
    std::thread::sleep(std::time::Duration::from_millis(20));
    assert!(matches!(unbounded.read(&mut out), Ok(n) if n >= 500), "every sample due, in batches");
}
