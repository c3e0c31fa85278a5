//! The 8350's live I/O state, shared by the Modbus map and the board's capture and output
//! paths: a blocking mutex held for microseconds only (never across a flash commit), so the
//! engines catch up with the hardware even while a settings write is being committed.

use core::cell::RefCell;

use embassy_futures::select::{select, Either};
use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_time::{Duration, Instant, Ticker, Timer};

use remodaq_shared::diagnostics::{status, DIAGNOSTICS};

use crate::di::DiEngine;
use crate::pulse::{self, PulseEngine};
use crate::settings::Settings;
use crate::watchdog::HostWatchdog;

/// The engines and the extra-pulses registers.
pub struct Io {
    /// The input engine.
    pub di: DiEngine,
    /// The output engine.
    pub pulse: PulseEngine,
    /// DO n extra pulses register (40061 + 2n): the last value written.
    pub extra: [u32; pulse::CHANNELS],
    /// The host watchdog (extensions §3).
    pub watchdog: HostWatchdog,
    /// The outputs' levels in the watchdog's safe state.
    safe: u8,
}

impl Io {
    /// Engines for inputs sampled `sample_rate` times a second, configured from `settings`,
    /// with the outputs at their power-on values.
    pub fn new(sample_rate: u32, settings: &Settings) -> Self {
        let mut io = Self {
            di: DiEngine::new(sample_rate),
            pulse: PulseEngine::new(),
            extra: [0; pulse::CHANNELS],
            watchdog: HostWatchdog::new(settings.watchdog, Instant::now()),
            safe: settings.safe,
        };
        io.configure(settings);
        io.pulse.hold(settings.power_on);
        io
    }

    /// A Modbus request was served (`write`: a write request): feeds the host watchdog.
    pub fn request(&mut self, write: bool) {
        if self.watchdog.request(write, Instant::now()) {
            self.watchdog_cleared();
        }
    }

    /// Checks the host watchdog at `now`; on a trip, every output goes to its safe level and
    /// every pulse train stops.
    pub fn poll_watchdog(&mut self, now: Instant) {
        if self.watchdog.poll(now) {
            self.pulse.hold(self.safe);
            DIAGNOSTICS.set(status::HOST_WATCHDOG, true);
            remodaq_shared::warn!("host watchdog: no request in time, outputs in the safe state {:02X}h", self.safe);
        }
    }

    /// Holds the outputs at their safe levels again if the watchdog is tripped (after a
    /// change that might have moved them); true when it is.
    pub fn keep_safe(&mut self) -> bool {
        if self.watchdog.tripped() {
            self.pulse.hold(self.safe);
        }
        self.watchdog.tripped()
    }

    /// Ends the safe state (0 written to 40308); the outputs keep their levels until written.
    pub fn clear_watchdog(&mut self) {
        if self.watchdog.tripped() {
            self.watchdog.clear();
            self.watchdog_cleared();
        }
    }

    fn watchdog_cleared(&mut self) {
        DIAGNOSTICS.set(status::HOST_WATCHDOG, false);
        remodaq_shared::info!("host watchdog: safe state cleared");
    }

    /// Applies the persisted settings (modes, pulse settings, watchdog); only changes take
    /// effect.
    pub fn configure(&mut self, settings: &Settings) {
        self.watchdog.configure(settings.watchdog, Instant::now());
        self.safe = settings.safe;
        for (n, mode) in settings.di_modes.iter().enumerate() {
            self.di.set_mode(n, *mode);
        }
        for n in 0..pulse::CHANNELS {
            self.pulse.set_mode(n, settings.do_modes[n]);
            self.pulse.set_config(n, settings.pulses[n]);
        }
    }
}

/// [`Io`] behind its mutex.
pub type IoCell<R> = Mutex<R, RefCell<Io>>;

/// Runs `f` on the I/O state.
pub fn with<R: RawMutex, T>(cell: &IoCell<R>, f: impl FnOnce(&mut Io) -> T) -> T {
    cell.lock(|io| f(&mut io.borrow_mut()))
}

/// How often the captured input samples are handed to the engine (the STM32 capture ring holds
/// 82 ms, so this leaves a wide margin). Each pass is the application's heartbeat.
pub const DRAIN_INTERVAL: Duration = Duration::from_millis(2);
/// Input samples taken from the capture per read (the drain reads until the capture is empty:
/// 100 samples are due every 2 ms at 50 kHz). 256: the buffer lives in the application task's
/// static future, and 512 took the 8350 over its RAM goal once the flash lock came (issue #21).
pub const DRAIN_BATCH: usize = 256;
/// Input samples processed per lock of the I/O state, and output ticks computed per lock. The
/// lock is a critical section (interrupts off on the target): at most 58 instructions a
/// sample with edges on all 12 inputs and 225 a tick for 6 pulse trains (`tools/m4-cost`),
/// 32 samples are about 1 900 and 12 ticks about 2 700 instructions: under 20 µs (3 600
/// instructions) at 180 MHz, goals that `tools/m4-cost` counts (16 ticks came to 3 600 exactly).
pub const LOCKED_SAMPLES: usize = 32;
/// See [`LOCKED_SAMPLES`].
pub const LOCKED_TICKS: usize = 12;
/// Output ticks computed per refill: half of the boards' output pattern ring (64 ticks, 6.4
/// ms). A command reaches the outputs one to two chunks later: 6.4 to 12.8 ms.
pub const OUTPUT_CHUNK: usize = 64;

/// The captured input samples were not drained in time: some were lost.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SamplesLost;

/// The output pattern ran dry before it was refilled: the outputs replayed old ticks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PatternUnderrun;

/// The board's input path: samples of all inputs (bit n = DIn) taken at
/// [`crate::di::SAMPLE_RATE_HZ`] by hardware (or in simulated time) into a ring.
pub trait InputCapture {
    /// Takes the samples captured since the last call, oldest first, as many as fit `out`.
    fn read(&mut self, out: &mut [u16]) -> Result<usize, SamplesLost>;
}

/// The board's output path: output levels (bit n = DOn), one per pulse-engine tick at
/// [`crate::pulse::TICK_HZ`], played from a ring of `2 * OUTPUT_CHUNK` ticks.
#[allow(async_fn_in_trait)]
pub trait OutputPattern {
    /// Queues `ticks` (at most [`OUTPUT_CHUNK`]), waiting until the ring has room for them.
    async fn write(&mut self, ticks: &[u8]) -> Result<(), PatternUnderrun>;
}

/// The 8350's application: drains the input capture into the DI engine every
/// [`DRAIN_INTERVAL`] (each pass calls `alive`), and keeps the output pattern filled from the
/// pulse engine, one [`OUTPUT_CHUNK`] at a time.
pub async fn run<R: RawMutex>(
    mut inputs: impl InputCapture,
    mut outputs: impl OutputPattern,
    cell: &IoCell<R>,
    mut alive: impl FnMut(),
) -> ! {
    let drain = async {
        let mut samples = [0u16; DRAIN_BATCH];
        let mut ticker = Ticker::every(DRAIN_INTERVAL);
        loop {
            ticker.next().await;
            loop {
                match inputs.read(&mut samples) {
                    Ok(0) => break,
                    Ok(n) => {
                        for part in samples[..n].chunks(LOCKED_SAMPLES) {
                            with(cell, |s| s.di.process(part));
                        }
                    }
                    Err(e) => {
                        remodaq_shared::error!("inputs: {:?}: samples were lost", e);
                        // Until the next read of the module status (extensions §1).
                        DIAGNOSTICS.set(status::FRONT_END_FAULT, true);
                        break;
                    }
                }
            }
            with(cell, |s| s.poll_watchdog(Instant::now()));
            if DIAGNOSTICS.set(status::INPUTS_PENDING, false) {
                remodaq_shared::info!("self-test: input capture running");
            }
            alive();
        }
    };
    let fill = async {
        let mut ticks = [0u8; OUTPUT_CHUNK];
        loop {
            for part in ticks.chunks_mut(LOCKED_TICKS) {
                with(cell, |s| s.pulse.fill(part));
            }
            if let Err(e) = outputs.write(&ticks).await {
                remodaq_shared::error!("outputs: {:?}: the pattern ran dry", e);
                DIAGNOSTICS.pattern_underrun();
            }
        }
    };
    match select(drain, fill).await {
        Either::First(never) | Either::Second(never) => never,
    }
}

/// Samples in the boards' capture ring: 4096, 82 ms at [`crate::di::SAMPLE_RATE_HZ`]. The STM32's
/// DMA ring holds this many; the QEMU board's simulated one too ([`SimulatedCapture::with_ring`]).
pub const CAPTURE_RING: usize = 4096;

/// A capture in simulated time (the host and QEMU boards): sample `index` since the start is
/// `sample_at(index)`; the samples due by now are handed out as the hardware ring would. A
/// sample given as `None` is lost (a fault the board injects): the read that meets it skips
/// every sample due and reports [`SamplesLost`], as the STM32's ring does when it overruns.
/// With a ring ([`with_ring`](Self::with_ring)), samples left undrained longer than the ring
/// lasts are lost the same way, as on the STM32.
pub struct SimulatedCapture<F> {
    start: Instant,
    done: u64,
    sample_at: F,
    ring: Option<u64>,
}

impl<F: FnMut(u64) -> Option<u16>> SimulatedCapture<F> {
    /// A capture starting now, whose ring never overruns (the host simulator: a busy PC must
    /// not lose inputs a module would not).
    pub fn new(sample_at: F) -> Self {
        Self { start: Instant::now(), done: 0, sample_at, ring: None }
    }

    /// A capture starting now through a ring of `ring` samples, which overruns as the STM32's
    /// does when the application drains it too late.
    pub fn with_ring(sample_at: F, ring: usize) -> Self {
        Self { ring: Some(ring as u64), ..Self::new(sample_at) }
    }
}

impl<F: FnMut(u64) -> Option<u16>> InputCapture for SimulatedCapture<F> {
    fn read(&mut self, out: &mut [u16]) -> Result<usize, SamplesLost> {
        let due = self.start.elapsed().as_micros() * u64::from(crate::di::SAMPLE_RATE_HZ) / 1_000_000;
        if self.ring.is_some_and(|ring| due.saturating_sub(self.done) > ring) {
            self.done = due;
            return Err(SamplesLost);
        }
        let n = (due.saturating_sub(self.done)).min(out.len() as u64) as usize;
        for (i, s) in out[..n].iter_mut().enumerate() {
            match (self.sample_at)(self.done + i as u64) {
                Some(sample) => *s = sample,
                None => {
                    self.done = due;
                    return Err(SamplesLost);
                }
            }
        }
        self.done += n as u64;
        Ok(n)
    }
}

/// An output ring played in simulated time (the host and QEMU boards): ticks are consumed at
/// [`pulse::TICK_HZ`] from the start; `played(first, levels)` sees each queued chunk and the
/// index of its first tick (ticks since the start: tick `k` plays at `k / TICK_HZ` s).
pub struct SimulatedPattern<F> {
    start: Instant,
    queued: u64,
    played: F,
}

impl<F: FnMut(u64, &[u8])> SimulatedPattern<F> {
    /// A ring starting now, empty.
    pub fn new(played: F) -> Self {
        Self { start: Instant::now(), queued: 0, played }
    }
}

impl<F: FnMut(u64, &[u8])> OutputPattern for SimulatedPattern<F> {
    async fn write(&mut self, ticks: &[u8]) -> Result<(), PatternUnderrun> {
        let tick_us = 1_000_000 / u64::from(pulse::TICK_HZ);
        let capacity = 2 * OUTPUT_CHUNK as u64;
        // Wait until the ring has played enough to take these ticks.
        let room_at = (self.queued + ticks.len() as u64).saturating_sub(capacity) * tick_us;
        Timer::at(self.start + Duration::from_micros(room_at)).await;
        let playing = self.start.elapsed().as_micros() / tick_us;
        let result = if playing > self.queued && self.queued > 0 { Err(PatternUnderrun) } else { Ok(()) };
        // After a late refill the ring plays on from where it is, as the DMA ring does.
        let first = self.queued.max(playing);
        self.queued = first + ticks.len() as u64;
        (self.played)(first, ticks);
        result
    }
}
