//! The 8350 register map (spec §3.1-3.2) on the shared Modbus core. Every address is decoded
//! once, by `remodaq_protocol::m8350::decode`, into the [`Point`] it names.
//!
//! Writes are planned on a copy first (the new settings, the extra pulses, the all-DO value),
//! which is both the validation and what gets applied: persisted settings are committed to
//! flash before anything reaches the outputs, so a failed commit (exception 04) changes nothing.

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_protocol::m8350::{
    decode, Point, PulseField, Word, BIT_COUNTER, BIT_DI, BIT_DO, DI_CHANNELS, DO_CHANNELS, MODULE_NAME, REG_COUNTER,
};
use remodaq_shared::access;
use remodaq_shared::diagnostics::{status, DIAGNOSTICS};
use remodaq_shared::identity::firmware_version;
use remodaq_shared::modbus::map::{allows_each, observe_registers_each, read_bits_each, read_registers_each};
use remodaq_shared::modbus::{Access, Exception, RegisterMap, Table, WriteValues};
use remodaq_shared::module::{write_update, SettingsAccess, Store, UpdateError};
use remodaq_shared::warn;

use crate::di::DiMode;
use crate::io::{self, IoCell};
use crate::pulse::{self, DoMode, PulseConfig};
use crate::settings::{output_values, watchdog_mode, watchdog_timeout, Settings};

fn field(p: &mut PulseConfig, f: PulseField) -> Option<&mut u32> {
    match f {
        PulseField::Low => Some(&mut p.low),
        PulseField::High => Some(&mut p.high),
        PulseField::Count => Some(&mut p.count),
        PulseField::Extra => None,
    }
}

/// A register write, planned.
#[derive(Clone, Copy)]
struct Plan {
    settings: Settings,
    extra: [u32; pulse::CHANNELS],
    /// Outputs whose extra-pulse register the request wrote (either word).
    extra_written: u8,
    /// Outputs whose extra-pulse low word the request wrote: the add happens for these (spec
    /// §3.4: once per request that writes the low word; a high word alone only stores).
    extra_added: u8,
    all_do: Option<u16>,
    /// 0 written to the watchdog status: end the safe state.
    clear_watchdog: bool,
    /// The request writes a register that could change an output (extensions §3).
    moves_output: bool,
}

/// The 8350's Modbus view: the settings in force (the store behind its own lock) and the
/// shared I/O state.
pub struct Map8350<'a, F: NorFlash, R: RawMutex> {
    store: &'a Store<F, Settings>,
    settings: Settings,
    io: &'a IoCell<R>,
    /// Whether the request being served may clear the flags it reads (extensions §4): set by
    /// [`RegisterMap::admit`], which the engine calls first for every request, under the same
    /// lock as the reads. False for a client outside a set allow-list, so it cannot consume the
    /// master's latch, overflow and "samples lost" events.
    reads_clear: bool,
}

/// Exception 04 for a write that would move an output while the host watchdog is tripped.
const TRIPPED: Exception = Exception::ServerDeviceFailure;

impl<'a, F: NorFlash, R: RawMutex> Map8350<'a, F, R> {
    /// A map over the store with `settings` in force; configures the engines from them.
    pub fn new(store: &'a Store<F, Settings>, settings: &Settings, io: &'a IoCell<R>) -> Self {
        io::with(io, |state| state.configure(settings));
        Self { store, settings: *settings, io, reads_clear: true }
    }

    /// A register write planned on `settings`; the errors are the request's exception 03.
    fn plan(io: &IoCell<R>, settings: &Settings, start: u16, values: &WriteValues<'_>) -> Result<Plan, Exception> {
        let mut plan = Plan {
            settings: *settings,
            extra: io::with(io, |s| s.extra),
            extra_written: 0,
            extra_added: 0,
            all_do: None,
            clear_watchdog: false,
            moves_output: false,
        };
        let bad = Exception::IllegalDataValue;
        for (i, v) in values.iter().enumerate() {
            let Some(point) = decode(Table::Registers, start + i as u16) else {
                return Err(Exception::IllegalDataAddress);
            };
            plan.moves_output |= point.moves_output();
            let s = &mut plan.settings;
            match point {
                Point::Pulse(f, n, word) => {
                    let n = usize::from(n);
                    match field(&mut s.pulses[n], f) {
                        Some(value) => *value = word.set(*value, v),
                        None => {
                            plan.extra[n] = word.set(plan.extra[n], v);
                            plan.extra_written |= 1 << n;
                            if word == Word::Low {
                                plan.extra_added |= 1 << n;
                            }
                        }
                    }
                }
                Point::DiMode(n) => s.di_modes[usize::from(n)] = DiMode::from_register(v).ok_or(bad)?,
                Point::DoMode(n) => s.do_modes[usize::from(n)] = DoMode::from_register(v).ok_or(bad)?,
                Point::AllDo => plan.all_do = Some(u16::from(output_values(v).ok_or(bad)?)),
                Point::WatchdogTimeout => s.watchdog.timeout = watchdog_timeout(v).ok_or(bad)?,
                Point::WatchdogMode => s.watchdog.mode = watchdog_mode(v).ok_or(bad)?,
                Point::SafeValues => s.safe = output_values(v).ok_or(bad)?,
                Point::PowerOnValues => s.power_on = output_values(v).ok_or(bad)?,
                Point::WatchdogStatus if v == 0 => plan.clear_watchdog = true,
                Point::WatchdogStatus => return Err(bad),
                _ => return Err(Exception::IllegalDataAddress),
            }
        }
        if plan.settings.pulses.iter().any(|p| p.low == 0 || p.high == 0) {
            return Err(bad);
        }
        Ok(plan)
    }

    /// The live part of a planned write, once its settings are in force: refused (and the
    /// safe levels kept) if it would move an output while the watchdog is tripped.
    fn apply_live(io: &IoCell<R>, plan: &Plan) -> Result<(), Exception> {
        io::with(io, |s| {
            if plan.moves_output && s.keep_safe() {
                return Err(TRIPPED);
            }
            for n in 0..pulse::CHANNELS {
                // Only the registers this request wrote: another client's write that landed
                // while this one was committing stays.
                if plan.extra_written & (1 << n) != 0 {
                    s.extra[n] = plan.extra[n];
                }
                if plan.extra_added & (1 << n) != 0 && plan.extra[n] > 0 {
                    s.pulse.add_pulses(n, plan.extra[n]);
                }
            }
            if let Some(all) = plan.all_do {
                for n in 0..pulse::CHANNELS {
                    s.pulse.set_do(n, all & (1 << n) != 0);
                }
                s.outputs_commanded();
            }
            if plan.clear_watchdog {
                s.clear_watchdog();
            }
            Ok(())
        })
    }

    /// A bit write, checked and applied in one lock of the I/O state.
    fn write_bits(io: &IoCell<R>, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        io::with(io, |s| {
            let points = || (start..).zip(values.iter()).map(|(a, v)| (decode(Table::Bits, a), v != 0));
            if s.watchdog.tripped() && points().any(|(p, _)| p.is_some_and(Point::moves_output)) {
                return Err(TRIPPED);
            }
            for (point, on) in points() {
                match (point, on) {
                    (Some(Point::Do(n)), _) => s.pulse.set_do(usize::from(n), on),
                    (Some(Point::CounterRun(n)), run) => s.di.set_run(usize::from(n), run),
                    (Some(Point::CounterClear(n)), true) => s.di.clear_counter(usize::from(n)),
                    (Some(Point::Overflow(n)), false) => s.di.clear_overflow(usize::from(n)),
                    (Some(Point::Latch(n)), false) => s.di.clear_latch(usize::from(n)),
                    // Decision: writing 0 to "clear", or 1 to a flag, changes nothing.
                    _ => {}
                }
            }
            s.outputs_commanded();
            Ok(())
        })
    }

    /// Counter registers `start..start + len` (spec §3.2), each given to `put` with its index,
    /// under one lock of the I/O state (a counter's two words belong together); `false` when
    /// the run is not inside the counters.
    fn counters(&self, start: u16, len: usize, mut put: impl FnMut(usize, u16)) -> bool {
        let first = start.checked_sub(REG_COUNTER).map(usize::from).filter(|i| i + len <= 2 * DI_CHANNELS);
        let Some(first) = first else { return false };
        io::with(self.io, |s| {
            for i in 0..len {
                let (n, w) = ((first + i) / 2, Word::of((first + i) as u16));
                put(i, w.get(s.di.counter_value(n)));
            }
        });
        true
    }

    fn read_point(&self, point: Point) -> u16 {
        let settings = &self.settings;
        io::with(self.io, |s| match point {
            Point::DiState(n) => s.di.state() >> n & 1,
            Point::Do(n) => u16::from(s.pulse.do_bit(usize::from(n))),
            Point::CounterRun(n) => u16::from(s.di.run(usize::from(n))),
            Point::CounterClear(_) => 0,
            Point::Overflow(n) => u16::from(s.di.take_overflow(usize::from(n))),
            Point::Latch(n) => u16::from(s.di.take_latch(usize::from(n))),
            Point::Counter(n, word) => word.get(s.di.counter_value(usize::from(n))),
            Point::Pulse(f, n, word) => {
                let mut p = settings.pulses[usize::from(n)];
                word.get(field(&mut p, f).map_or(s.extra[usize::from(n)], |v| *v))
            }
            Point::DiMode(n) => settings.di_modes[usize::from(n)] as u16,
            Point::DoMode(n) => settings.do_modes[usize::from(n)] as u16,
            Point::AllDi => s.di.state(),
            Point::AllDo => s.pulse.do_bits(),
            Point::Name => MODULE_NAME,
            Point::Version => firmware_version(),
            // "Samples lost since the last read of this register": cleared by the read.
            Point::Diag(d) => DIAGNOSTICS.read(d, status::FRONT_END_FAULT),
            Point::WatchdogTimeout => settings.watchdog.timeout,
            Point::WatchdogMode => settings.watchdog.mode,
            Point::SafeValues => u16::from(settings.safe),
            Point::PowerOnValues => u16::from(settings.power_on),
            Point::WatchdogStatus => u16::from(s.watchdog.tripped()),
        })
    }
}

impl<F: NorFlash, R: RawMutex> RegisterMap for Map8350<'_, F, R> {
    fn access(&self, table: Table, addr: u16) -> Access {
        remodaq_protocol::m8350::access(table, addr)
    }

    fn protects(&self, from: [u8; 4]) -> bool {
        !self.settings.allow.is_empty() && self.settings.allow.allows(from)
    }

    fn admit(&mut self, from: [u8; 4], function: u8) -> Result<(), Exception> {
        // Reads with a side effect (clear-on-read) are for those who may write: anyone while no
        // allow-list is set, else its clients only; the others read the flags as they stand.
        let allowed = self.settings.allow.allows(from);
        self.reads_clear = allowed;
        access::admit(&self.settings.allow, from, function)?;
        // With an allow-list, only its clients feed (and auto-clear) the host watchdog: a
        // reader elsewhere on the LAN cannot keep a dead master's outputs alive (docs/security.md).
        if allowed {
            io::with(self.io, |s| s.request(access::is_write(function)));
        }
        Ok(())
    }

    fn read(&mut self, table: Table, addr: u16) -> u16 {
        if !self.reads_clear {
            return self.observe(table, addr);
        }
        decode(table, addr).map_or(0, |point| self.read_point(point))
    }

    /// The overflow and latch flags and the status's "samples lost" bit as they stand, not
    /// cleared.
    fn observe(&mut self, table: Table, addr: u16) -> u16 {
        match decode(table, addr) {
            Some(Point::Overflow(n)) => io::with(self.io, |s| s.di.flags().0) >> n & 1,
            Some(Point::Latch(n)) => io::with(self.io, |s| s.di.flags().1) >> n & 1,
            Some(Point::Diag(d)) => DIAGNOSTICS.read(d, 0),
            point => point.map_or(0, |point| self.read_point(point)),
        }
    }

    /// The runs a poll reads or writes are checked in one go (spec §3.1): the DI states (read
    /// only), the DOs, the counter bits and the counters (read only); others address by address.
    fn allows(&self, table: Table, start: u16, count: u16, write: bool) -> bool {
        let within = |base: u16, len: usize| start >= base && usize::from(start - base) + usize::from(count) <= len;
        let block = match table {
            Table::Bits => {
                (!write && within(BIT_DI, DI_CHANNELS))
                    || within(BIT_DO, DO_CHANNELS)
                    || within(BIT_COUNTER, 4 * DI_CHANNELS)
            }
            Table::Registers => !write && within(REG_COUNTER, 2 * DI_CHANNELS),
        };
        block || allows_each(self, table, start, count, write)
    }

    /// The DI states, the DOs and the counters are read under one lock of the I/O state; other
    /// runs point by point.
    fn read_bits(&mut self, start: u16, count: u16, out: &mut [u8]) {
        let within = |base: u16, len: usize| start.checked_sub(base).filter(|i| usize::from(i + count) <= len);
        let word = if let Some(i) = within(BIT_DI, DI_CHANNELS) {
            io::with(self.io, |s| s.di.state()) >> i
        } else if let Some(i) = within(BIT_DO, DO_CHANNELS) {
            io::with(self.io, |s| s.pulse.do_bits()) >> i
        } else {
            return read_bits_each(self, start, count, out);
        };
        let word = word & ((1u32 << count) - 1) as u16;
        for (byte, value) in out.iter_mut().zip(word.to_le_bytes()) {
            *byte = value;
        }
    }

    fn read_registers(&mut self, start: u16, out: &mut [u8]) {
        let counters = self.counters(start, out.len() / 2, |i, v| {
            if let Some(word) = out.get_mut(2 * i..2 * i + 2) {
                word.copy_from_slice(&v.to_be_bytes());
            }
        });
        if !counters {
            read_registers_each(self, start, out)
        }
    }

    /// The counters' words together, as a Modbus read of them gets them.
    fn observe_registers(&mut self, start: u16, out: &mut [u16]) {
        let counters = self.counters(start, out.len(), |i, v| {
            if let Some(word) = out.get_mut(i) {
                *word = v;
            }
        });
        if !counters {
            observe_registers_each(self, start, out)
        }
    }

    /// A write that touches RAM only (the bits, the extra pulses, the all-DO register, the
    /// watchdog's clear) is carried out at once; a write that changes a setting is left to
    /// [`RegisterMap::write`], which commits it without the map's lock.
    fn write_now(&mut self, start: u16, values: &WriteValues<'_>) -> Option<Result<(), Exception>> {
        if values.table() == Table::Bits {
            return Some(Self::write_bits(self.io, start, values));
        }
        match Self::plan(self.io, &self.settings, start, values) {
            Ok(plan) if plan.settings == self.settings => Some(Self::apply_live(self.io, &plan)),
            Ok(_) => None,
            Err(e) => Some(Err(e)),
        }
    }

    fn validate(&self, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        match values.table() {
            Table::Bits => Ok(()),
            Table::Registers => Self::plan(self.io, &self.settings, start, values).map(|_| ()),
        }
    }

    /// Persisted settings are committed to flash (without the map's lock) before anything
    /// reaches the outputs, so a failed commit (exception 04) changes nothing.
    async fn write<R2: RawMutex>(map: &Mutex<R2, Self>, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        let (store, io) = {
            // Decided in this block, which has no await: the copy of the settings and the plan
            // are not kept in the future through the commit (every Modbus slot's task holds
            // one: issue #40, the STM32's RAM).
            let (store, io, settings) = {
                let m = map.lock().await;
                (m.store, m.io, m.settings)
            };
            if values.table() == Table::Bits {
                return Self::write_bits(io, start, values);
            }
            let plan = Self::plan(io, &settings, start, values)?;
            if plan.settings == settings {
                return Self::apply_live(io, &plan);
            }
            if plan.moves_output && io::with(io, |s| s.watchdog.tripped()) {
                return Err(TRIPPED);
            }
            (store, io)
        };
        // Planned again on the latest settings, under the store's lock.
        // Within the commit budget (flash wear): beyond it, exception 04 and nothing changes.
        let plan = write_update(map, store, |s| {
            let plan = Self::plan(io, s, start, values)?;
            *s = plan.settings;
            Ok(plan)
        })
        .await
        .map_err(|e| match e {
            UpdateError::Refused(e) => e,
            UpdateError::Store(e) => {
                warn!("8350: settings commit failed: {:?}", e);
                Exception::ServerDeviceFailure
            }
        })?;
        Self::apply_live(io, &plan)
    }
}

impl<F: NorFlash, R: RawMutex> SettingsAccess for Map8350<'_, F, R> {
    type Settings = Settings;
    fn settings(&self) -> &Settings {
        &self.settings
    }
    fn committed(&mut self, settings: &Settings) {
        self.settings = *settings;
        io::with(self.io, |s| s.configure(settings));
    }
}
