//! The module's diagnostics (extensions §1): what the diagnostics registers read, kept in one
//! static of atomics. The connection server counts requests, exceptions and connections; the
//! module's application sets and clears its fault bits; the register maps read it all through
//! [`Diagnostics::read`]. One module runs per firmware image (and per simulator process).

use core::sync::atomic::{AtomicU16, AtomicU32, Ordering};

use embassy_time::Instant;
pub use remodaq_protocol::diag::{mqtt, reset_cause, security, status, Diag};
use remodaq_protocol::Word;

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

/// A security event counted in the diagnostics registers (docs/diagnostics.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Security {
    /// A wrong proof (its source is kept as the last failed source).
    AuthFailure,
    /// A proof not checked: the guessing budget was spent.
    BudgetRefusal,
    /// A Modbus write refused by the allow-list.
    AccessRefusal,
    /// A firmware update refused.
    UpdateRefusal,
    /// A settings write refused: the commit budget was spent.
    WriteBudgetRefusal,
}

/// The counters and flags behind the diagnostics registers.
pub struct Diagnostics {
    status: AtomicU16,
    reset_cause: AtomicU16,
    connections: AtomicU16,
    requests: AtomicU32,
    exceptions: AtomicU16,
    security: AtomicU16,
    auth_failures: AtomicU16,
    last_failed_source: AtomicU32,
    budget_refusals: AtomicU16,
    access_refusals: AtomicU16,
    update_refusals: AtomicU16,
    write_budget_refusals: AtomicU16,
    update_key: AtomicU32x2,
    pattern_underruns: AtomicU16,
    output_latency: AtomicU16,
    output_latency_worst: AtomicU16,
    mqtt: [AtomicU16; mqtt::REGISTERS as usize],
}

/// Two 32-bit atomics (the update key's fingerprint: no 64-bit atomics on the Cortex-M4).
struct AtomicU32x2([AtomicU32; 2]);

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
            security: AtomicU16::new(0),
            auth_failures: AtomicU16::new(0),
            last_failed_source: AtomicU32::new(0),
            budget_refusals: AtomicU16::new(0),
            access_refusals: AtomicU16::new(0),
            update_refusals: AtomicU16::new(0),
            write_budget_refusals: AtomicU16::new(0),
            update_key: AtomicU32x2([AtomicU32::new(0), AtomicU32::new(0)]),
            pattern_underruns: AtomicU16::new(0),
            output_latency: AtomicU16::new(0),
            output_latency_worst: AtomicU16::new(0),
            mqtt: [const { AtomicU16::new(0) }; mqtt::REGISTERS as usize],
        }
    }

    /// Counts a security event from `from`.
    pub fn security(&self, event: Security, from: [u8; 4]) {
        let counter = match event {
            Security::AuthFailure => {
                self.last_failed_source.store(u32::from_be_bytes(from), Ordering::Relaxed);
                &self.auth_failures
            }
            Security::BudgetRefusal => &self.budget_refusals,
            Security::AccessRefusal => &self.access_refusals,
            Security::UpdateRefusal => &self.update_refusals,
            Security::WriteBudgetRefusal => &self.write_budget_refusals,
        };
        counter.fetch_add(1, Ordering::Relaxed);
    }

    /// Whether the factory password is in force (security flag bit 0).
    pub fn factory_password(&self, on: bool) {
        if on {
            self.security.fetch_or(security::FACTORY_PASSWORD, Ordering::Relaxed);
        } else {
            self.security.fetch_and(!security::FACTORY_PASSWORD, Ordering::Relaxed);
        }
    }

    /// The fingerprint of the firmware update key (registers 40321-40324).
    pub fn update_key(&self, fingerprint: [u8; 8]) {
        let [a, b, c, d, e, f, g, h] = fingerprint;
        self.update_key.0[0].store(u32::from_be_bytes([a, b, c, d]), Ordering::Relaxed);
        self.update_key.0[1].store(u32::from_be_bytes([e, f, g, h]), Ordering::Relaxed);
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

    /// The 8350's output pattern ran dry before it was refilled (register 40325).
    pub fn pattern_underrun(&self) {
        self.pattern_underruns.fetch_add(1, Ordering::Relaxed);
    }

    /// The 8350 played an output command `us` µs after it was given (registers 40326-40327).
    pub fn output_latency(&self, us: u64) {
        let us = u16::try_from(us).unwrap_or(u16::MAX);
        self.output_latency.store(us, Ordering::Relaxed);
        self.output_latency_worst.fetch_max(us, Ordering::Relaxed);
    }

    /// MQTT's state (register 40328, [`mqtt::OFF`] ...).
    pub fn mqtt_state(&self, state: u16) {
        self.mqtt[usize::from(mqtt::STATE)].store(state, Ordering::Relaxed);
    }

    /// One more of MQTT's events `n` ([`mqtt::SESSIONS`] ..., registers 40329-40333).
    pub fn mqtt_event(&self, n: u8) {
        if let Some(counter) = self.mqtt.get(usize::from(n)).filter(|_| n != mqtt::STATE) {
            counter.fetch_add(1, Ordering::Relaxed);
        }
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
            Diag::Security => self.security.load(Ordering::Relaxed),
            Diag::AuthFailures => self.auth_failures.load(Ordering::Relaxed),
            // a.b first, then c.d (the address as written).
            Diag::LastFailedSource(w) => {
                let ip = self.last_failed_source.load(Ordering::Relaxed);
                match w {
                    Word::Low => (ip >> 16) as u16,
                    Word::High => ip as u16,
                }
            }
            Diag::BudgetRefusals => self.budget_refusals.load(Ordering::Relaxed),
            Diag::AccessRefusals => self.access_refusals.load(Ordering::Relaxed),
            Diag::UpdateRefusals => self.update_refusals.load(Ordering::Relaxed),
            Diag::WriteBudgetRefusals => self.write_budget_refusals.load(Ordering::Relaxed),
            Diag::PatternUnderruns => self.pattern_underruns.load(Ordering::Relaxed),
            Diag::OutputLatency => self.output_latency.load(Ordering::Relaxed),
            Diag::OutputLatencyWorst => self.output_latency_worst.load(Ordering::Relaxed),
            Diag::Mqtt(n) => self.mqtt.get(usize::from(n)).map_or(0, |r| r.load(Ordering::Relaxed)),
            Diag::UpdateKey(i) => {
                let half = self.update_key.0[usize::from(i / 2) % 2].load(Ordering::Relaxed);
                if i % 2 == 0 {
                    (half >> 16) as u16
                } else {
                    half as u16
                }
            }
        }
    }
}

impl Default for Diagnostics {
    fn default() -> Self {
        Self::new()
    }
}
