//! The 8350's live I/O state, shared by the Modbus map and the board's capture and output
//! paths: a blocking mutex held for microseconds only (never across a flash commit), so the
//! engines catch up with the hardware even while a settings write is being committed.

use core::cell::RefCell;

use embassy_futures::select::{select, Either};
use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::waitqueue::WakerRegistration;
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
    /// When the first output command not yet in the pattern was given.
    commanded_at: Option<Instant>,
    /// The output task, waiting for a command to write into the queued pattern.
    output_task: WakerRegistration,
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
            commanded_at: None,
            output_task: WakerRegistration::new(),
        };
        io.configure(settings);
        io.pulse.hold(settings.power_on);
        // The power-on levels are in the first ticks computed: nothing to write into a pattern
        // (and no client command to measure).
        io.pulse.take_commanded();
        io.commanded_at = None;
        io
    }

    /// A Modbus request was served (`write`: a write request): feeds the host watchdog.
    pub fn request(&mut self, write: bool) {
        if self.watchdog.request(write, Instant::now()) {
            self.watchdog_cleared();
        }
    }

    /// To call once commands have changed outputs (a DO bit, a hold, a mode): the output task
    /// writes the new levels into the pattern already queued, a few ticks ahead of the one
    /// playing ([`OutputPattern::force`]), rather than at its next refill.
    pub fn outputs_commanded(&mut self) {
        if self.pulse.commanded() == 0 {
            return;
        }
        if self.commanded_at.is_none() {
            self.commanded_at = Some(Instant::now());
        }
        self.output_task.wake();
    }

    /// Checks the host watchdog at `now`; on a trip, every output goes to its safe level and
    /// every pulse train stops.
    pub fn poll_watchdog(&mut self, now: Instant) {
        if self.watchdog.poll(now) {
            self.pulse.hold(self.safe);
            self.outputs_commanded();
            DIAGNOSTICS.set(status::HOST_WATCHDOG, true);
            remodaq_shared::warn!("host watchdog: no request in time, outputs in the safe state {:02X}h", self.safe);
        }
    }

    /// Holds the outputs at their safe levels again if the watchdog is tripped (after a
    /// change that might have moved them); true when it is.
    pub fn keep_safe(&mut self) -> bool {
        if self.watchdog.tripped() {
            self.pulse.hold(self.safe);
            self.outputs_commanded();
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
        self.outputs_commanded();
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
/// ms). A command does not wait for them: it is written into the ticks already queued
/// ([`OutputPattern::force`]).
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
    /// Waits until the ring has room for [`OUTPUT_CHUNK`] ticks; queues nothing (a wait
    /// dropped half way leaves the ring as it was).
    async fn room(&mut self);

    /// Queues `ticks` (at most [`OUTPUT_CHUNK`], the room [`room`](Self::room) waited for) after
    /// those queued. Returns how many ticks after the one playing now the first of them plays.
    fn write(&mut self, ticks: &[u8]) -> Result<u32, PatternUnderrun>;

    /// Forces the outputs of `mask` to their bit in `levels` in every queued tick from
    /// [`FORCE_AHEAD`] ticks after the one playing now. Returns how many ticks after the one
    /// playing the forced levels start: [`FORCE_AHEAD`], or fewer when fewer ticks are queued
    /// (the ticks written next carry them).
    fn force(&mut self, mask: u8, levels: u8) -> u32;
}

/// Ticks between the one playing and the first one [`OutputPattern::force`] rewrites (0.3 ms):
/// room for the DMA's read of the next tick and for the rewrite itself, interrupts allowed.
pub const FORCE_AHEAD: u32 = 3;

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
        if !FORCE {
            // As before issue #23: a chunk is computed, then queued once there is room, so a
            // command reaches the outputs 12.8 to 19.2 ms later.
            loop {
                let at = compute(cell, &mut ticks);
                outputs.room().await;
                if let (Some(ahead), Some(at)) = (queue(&mut outputs, &ticks), at) {
                    output_latency(at, ahead);
                }
            }
        }
        loop {
            // A command first: the engine must not compute past it before its outputs are
            // forced (a short train it stopped and another started could otherwise end inside
            // the engine and look steady).
            match select(commanded(cell), outputs.room()).await {
                Either::Second(()) => {
                    compute(cell, &mut ticks);
                    queue(&mut outputs, &ticks);
                }
                Either::First(at) => {
                    // The commanded outputs that hold a level: a train a command started begins
                    // at the next refill, exact; one it stopped ends here.
                    let (mask, levels) = with(cell, |s| {
                        let (steady, levels) = s.pulse.steady();
                        (s.pulse.take_commanded() & steady, levels)
                    });
                    if mask != 0 {
                        output_latency(at, outputs.force(mask, levels));
                    }
                }
            }
        }
    };
    match select(drain, fill).await {
        Either::First(never) | Either::Second(never) => never,
    }
}

/// Whether output commands are written into the queued pattern ([`OutputPattern::force`]);
/// off with the feature `refill-only` (the behaviour before issue #23, for comparisons): they
/// then reach the outputs with a chunk computed after them, 12.8 to 19.2 ms later.
const FORCE: bool = !cfg!(feature = "refill-only");

/// Computes the next chunk of ticks; the time of the first command they are the first to carry
/// (used without forcing).
fn compute<R: RawMutex>(cell: &IoCell<R>, ticks: &mut [u8; OUTPUT_CHUNK]) -> Option<Instant> {
    for part in ticks.chunks_mut(LOCKED_TICKS) {
        with(cell, |s| s.pulse.fill(part));
    }
    if FORCE {
        None
    } else {
        with(cell, |s| s.commanded_at.take())
    }
}

/// Queues a computed chunk (there is room); how many ticks after the one playing it starts, or
/// `None` when the pattern ran dry (counted, 40325).
fn queue(outputs: &mut impl OutputPattern, ticks: &[u8]) -> Option<u32> {
    match outputs.write(ticks) {
        Ok(ahead) => Some(ahead),
        Err(e) => {
            remodaq_shared::error!("outputs: {:?}: the pattern ran dry", e);
            DIAGNOSTICS.pattern_underrun();
            None
        }
    }
}

/// Waits for an output command not yet in the pattern; the time it was given.
async fn commanded<R: RawMutex>(cell: &IoCell<R>) -> Instant {
    if !FORCE {
        return core::future::pending().await;
    }
    core::future::poll_fn(|cx| {
        with(cell, |s| match s.commanded_at.take() {
            Some(at) => core::task::Poll::Ready(at),
            None => {
                s.output_task.register(cx.waker());
                core::task::Poll::Pending
            }
        })
    })
    .await
}

/// Counts the latency of an output command given at `at`, whose levels play `ahead` ticks
/// after the one playing now (diagnostics 40326-40327).
fn output_latency(at: Instant, ahead: u32) {
    let us = at.elapsed().as_micros() + u64::from(ahead) * TICK_US;
    DIAGNOSTICS.output_latency(us);
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
/// [`pulse::TICK_HZ`] from the start; `played(first, levels)` sees the ticks queued from tick
/// `first` on (ticks since the start: tick `k` plays at `k / TICK_HZ` s), each call replacing
/// what an earlier one said of the ticks from `first` on (a forced rewrite).
pub struct SimulatedPattern<F> {
    start: Instant,
    queued: u64,
    /// The queued ticks, tick `k` at `k % RING`.
    ring: [u8; RING],
    played: F,
}

/// The simulated ring's length, ticks: the STM32's.
const RING: usize = 2 * OUTPUT_CHUNK;
/// One tick, µs.
const TICK_US: u64 = 1_000_000 / pulse::TICK_HZ as u64;

impl<F: FnMut(u64, &[u8])> SimulatedPattern<F> {
    /// A ring starting now, empty.
    pub fn new(played: F) -> Self {
        Self { start: Instant::now(), queued: 0, ring: [0; RING], played }
    }

    /// The tick playing now.
    fn playing(&self) -> u64 {
        self.start.elapsed().as_micros() / TICK_US
    }
}

impl<F: FnMut(u64, &[u8])> OutputPattern for SimulatedPattern<F> {
    async fn room(&mut self) {
        // Room once the ring has played enough to take a chunk.
        let room_at = (self.queued + OUTPUT_CHUNK as u64).saturating_sub(RING as u64) * TICK_US;
        Timer::at(self.start + Duration::from_micros(room_at)).await;
    }

    fn write(&mut self, ticks: &[u8]) -> Result<u32, PatternUnderrun> {
        let playing = self.playing();
        let result = if playing > self.queued && self.queued > 0 { Err(PatternUnderrun) } else { Ok(()) };
        // After a late refill the ring plays on from where it is, as the DMA ring does.
        let first = self.queued.max(playing);
        for (k, &levels) in (first..).zip(ticks) {
            self.ring[(k % RING as u64) as usize] = levels;
        }
        self.queued = first + ticks.len() as u64;
        (self.played)(first, ticks);
        result.map(|()| (first - playing) as u32)
    }

    fn force(&mut self, mask: u8, levels: u8) -> u32 {
        let playing = self.playing();
        let from = playing + u64::from(FORCE_AHEAD);
        if from >= self.queued {
            return self.queued.saturating_sub(playing) as u32;
        }
        let mut rewritten = [0u8; RING];
        for (k, out) in (from..self.queued).zip(&mut rewritten) {
            let tick = &mut self.ring[(k % RING as u64) as usize];
            *tick = (*tick & !mask) | (levels & mask);
            *out = *tick;
        }
        (self.played)(from, &rewritten[..(self.queued - from) as usize]);
        FORCE_AHEAD
    }
}
