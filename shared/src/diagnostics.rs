//! The module's diagnostics (extensions §1): what the diagnostics registers read, kept in one
//! static of atomics. The connection server counts requests, exceptions and connections; the
//! module's application sets and clears its fault bits; the register maps read it all through
//! [`Diagnostics::read`]. One module runs per firmware image (and per simulator process).

use core::sync::atomic::{AtomicU16, AtomicU32, Ordering};

use embassy_time::Instant;
pub use remodaq_protocol::diag::{reset_cause, status, Diag};

/// Why this run started (register 40244).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u16)]
pub enum ResetCause {
    /// Power-on.
    PowerOn = reset_cause::POWER_ON,
    /// Watchdog.
    Watchdog = reset_cause::WATCHDOG,
    /// Software restart (restart command, firmware update).
    Software = reset_cause::SOFTWARE,
    /// Reset pin.
    Pin = reset_cause::PIN,
    /// Brown-out.
    BrownOut = reset_cause::BROWN_OUT,
    /// The board cannot tell.
    Unknown = reset_cause::UNKNOWN,
}

/// The counters and flags behind the diagnostics registers.
pub struct Diagnostics {
    status: AtomicU16,
    reset_cause: AtomicU16,
    connections: AtomicU16,
    requests: AtomicU32,
    exceptions: AtomicU16,
}

/// The module's diagnostics.
pub static DIAGNOSTICS: Diagnostics = Diagnostics::new();

impl Diagnostics {
    /// Nothing counted, inputs pending.
    pub const fn new() -> Self {
        Self {
            status: AtomicU16::new(status::INPUTS_PENDING),
            reset_cause: AtomicU16::new(ResetCause::Unknown as u16),
            connections: AtomicU16::new(0),
            requests: AtomicU32::new(0),
            exceptions: AtomicU16::new(0),
        }
    }

    /// Records the reset cause at start-up (a watchdog reset also sets its status bit).
    pub fn start(&self, cause: ResetCause) {
        self.reset_cause.store(cause as u16, Ordering::Relaxed);
        self.set(status::WATCHDOG_RESET, cause == ResetCause::Watchdog);
    }

    /// Sets (`on`) or clears status `bits`; returns whether they changed (to log transitions).
    pub fn set(&self, bits: u16, on: bool) -> bool {
        let before = if on {
            self.status.fetch_or(bits, Ordering::Relaxed)
        } else {
            self.status.fetch_and(!bits, Ordering::Relaxed)
        };
        (before & bits != 0) != on
    }

    /// A settings commit ended: a failed one sets the store-fault bit, a good one clears it.
    pub fn committed<T, E>(&self, result: &Result<T, E>) {
        if self.set(status::STORE_FAULT, result.is_err()) && result.is_err() {
            crate::error!("diagnostics: settings store fault (a commit failed)");
        }
    }

    /// The module status, without clearing anything.
    pub fn status(&self) -> u16 {
        self.status.load(Ordering::Relaxed)
    }

    /// A request was answered (`exception`: with an exception response).
    pub fn answered(&self, exception: bool) {
        self.requests.fetch_add(1, Ordering::Relaxed);
        if exception {
            self.exceptions.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// A client connected (`true`) or went (`false`).
    pub fn connection(&self, open: bool) {
        if open {
            self.connections.fetch_add(1, Ordering::Relaxed);
        } else {
            // Down by one, never below zero (a compare-and-swap loop).
            let mut n = self.connections.load(Ordering::Relaxed);
            while n > 0 {
                match self.connections.compare_exchange_weak(n, n - 1, Ordering::Relaxed, Ordering::Relaxed) {
                    Ok(_) => break,
                    Err(now) => n = now,
                }
            }
        }
    }

    /// The value of diagnostics register `d`. Reading the module status clears the 8350's
    /// "samples lost" bit (it means lost since the last read); `clear_on_read` says which bits
    /// the module clears that way.
    pub fn read(&self, d: Diag, clear_on_read: u16) -> u16 {
        match d {
            Diag::Status => self.status.fetch_and(!clear_on_read, Ordering::Relaxed),
            Diag::Uptime(w) => w.get(Instant::now().as_secs() as u32),
            Diag::ResetCause => self.reset_cause.load(Ordering::Relaxed),
            Diag::Connections => self.connections.load(Ordering::Relaxed),
            Diag::Requests(w) => w.get(self.requests.load(Ordering::Relaxed)),
            Diag::Exceptions => self.exceptions.load(Ordering::Relaxed),
        }
    }
}

impl Default for Diagnostics {
    fn default() -> Self {
        Self::new()
    }
}
