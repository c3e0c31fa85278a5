//! The 8350's live I/O state, shared by the Modbus map and the board's capture and output
//! paths: a blocking mutex held for microseconds only (never across a flash commit), so the
//! engines catch up with the hardware even while a settings write is being committed.

use core::cell::RefCell;

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::blocking_mutex::Mutex;

use crate::di::DiEngine;
use crate::pulse::{self, PulseEngine};
use crate::settings::Settings;

/// The engines and the extra-pulses registers.
pub struct Io {
    /// The input engine.
    pub di: DiEngine,
    /// The output engine.
    pub pulse: PulseEngine,
    /// DO n extra pulses register (40061 + 2n): the last value written.
    pub extra: [u32; pulse::CHANNELS],
}

impl Io {
    /// Engines for inputs sampled `sample_rate` times a second, configured from `settings`.
    pub fn new(sample_rate: u32, settings: &Settings) -> Self {
        let mut io = Self { di: DiEngine::new(sample_rate), pulse: PulseEngine::new(), extra: [0; pulse::CHANNELS] };
        io.configure(settings);
        io
    }

    /// Applies the persisted settings (modes and pulse settings); only changes take effect.
    pub fn configure(&mut self, settings: &Settings) {
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

/// Feeds the engines in simulated time (the host and QEMU boards): the input samples and
/// output ticks that fell due since the start, in batches, through the same engine calls as
/// the STM32's hardware paths.
#[derive(Default)]
pub struct Simulation {
    samples_done: u64,
    ticks_done: u64,
}

impl Simulation {
    /// Catches up to `elapsed_us` since the start: `sample_at(index)` gives input sample
    /// `index` (bit n = DIn); `ticks` sees each batch of output ticks computed.
    pub fn advance<R: RawMutex>(
        &mut self,
        cell: &IoCell<R>,
        elapsed_us: u64,
        mut sample_at: impl FnMut(u64) -> u16,
        mut ticks: impl FnMut(&[u8]),
    ) {
        let mut samples = [0u16; 256];
        let samples_due = elapsed_us * u64::from(crate::di::SAMPLE_RATE_HZ) / 1_000_000;
        while self.samples_done < samples_due {
            let n = (samples_due - self.samples_done).min(samples.len() as u64) as usize;
            for (i, s) in samples[..n].iter_mut().enumerate() {
                *s = sample_at(self.samples_done + i as u64);
            }
            with(cell, |state| state.di.process(&samples[..n]));
            self.samples_done += n as u64;
        }
        let mut levels = [0u8; 100];
        let ticks_due = elapsed_us * u64::from(pulse::TICK_HZ) / 1_000_000;
        while self.ticks_done < ticks_due {
            let n = (ticks_due - self.ticks_done).min(levels.len() as u64) as usize;
            with(cell, |state| state.pulse.fill(&mut levels[..n]));
            ticks(&levels[..n]);
            self.ticks_done += n as u64;
        }
    }
}
