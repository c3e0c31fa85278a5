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
