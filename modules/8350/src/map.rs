//! The 8350 register map (spec §3.1-3.2) on the shared Modbus core. Every address is decoded
//! once, by `remodaq_protocol::m8350::decode`, into the [`Point`] it names.
//!
//! Writes are planned on a copy first (the new settings, the extra pulses, the all-DO value),
//! which is both the validation and what gets applied: persisted settings are committed to
//! flash before anything reaches the outputs, so a failed commit (exception 04) changes nothing.

use embassy_sync::blocking_mutex::raw::RawMutex;
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_protocol::m8350::{decode, Point, PulseField, Word, DO_CHANNELS};
use remodaq_shared::diagnostics::{status, DIAGNOSTICS};
use remodaq_shared::identity::FIRMWARE_VERSION;
use remodaq_shared::modbus::{Access, Exception, RegisterMap, Table, WriteValues};
use remodaq_shared::module::SettingsAccess;
use remodaq_shared::settings::{SettingsStore, StoreError};
use remodaq_shared::warn;

pub use remodaq_protocol::m8350::{
    BIT_COUNTER, BIT_DI, BIT_DO, REG_ALL_DI, REG_ALL_DO, REG_COUNTER, REG_DI_MODE, REG_DO_MODE, REG_PULSE,
};

use crate::di::DiMode;
use crate::io::{self, IoCell};
use crate::pulse::{self, DoMode, PulseConfig};
use crate::settings::Settings;
use crate::MODULE_NAME;

fn field(p: &mut PulseConfig, f: PulseField) -> Option<&mut u32> {
    match f {
        PulseField::Low => Some(&mut p.low),
        PulseField::High => Some(&mut p.high),
        PulseField::Count => Some(&mut p.count),
        PulseField::Extra => None,
    }
}

/// A register write, planned.
struct Plan {
    settings: Settings,
    extra: [u32; pulse::CHANNELS],
    /// Outputs whose extra-pulse low word the request wrote: the add happens for these (spec
    /// §3.4: once per request that writes the low word; a high word alone only stores).
    extra_added: u8,
    all_do: Option<u16>,
}

/// The 8350's Modbus view: the settings store and the shared I/O state.
pub struct Map8350<'a, F: NorFlash, R: RawMutex> {
    store: SettingsStore<F, Settings>,
    io: &'a IoCell<R>,
}

impl<'a, F: NorFlash, R: RawMutex> Map8350<'a, F, R> {
    /// A map over the opened settings store; configures the engines from it.
    pub fn new(store: SettingsStore<F, Settings>, io: &'a IoCell<R>) -> Self {
        io::with(io, |state| state.configure(store.get()));
        Self { store, io }
    }

    /// Gives the settings store back (a simulated restart).
    pub fn into_store(self) -> SettingsStore<F, Settings> {
        self.store
    }

    fn plan(&self, start: u16, values: &WriteValues<'_>) -> Result<Plan, Exception> {
        let mut plan =
            Plan { settings: *self.store.get(), extra: io::with(self.io, |s| s.extra), extra_added: 0, all_do: None };
        for (i, v) in values.iter().enumerate() {
            match decode(Table::Registers, start + i as u16) {
                Some(Point::Pulse(f, n, word)) => {
                    let n = usize::from(n);
                    match field(&mut plan.settings.pulses[n], f) {
                        Some(value) => *value = word.set(*value, v),
                        None => {
                            plan.extra[n] = word.set(plan.extra[n], v);
                            if word == Word::Low {
                                plan.extra_added |= 1 << n;
                            }
                        }
                    }
                }
                Some(Point::DiMode(n)) => {
                    plan.settings.di_modes[usize::from(n)] =
                        DiMode::from_register(v).ok_or(Exception::IllegalDataValue)?;
                }
                Some(Point::DoMode(n)) => {
                    plan.settings.do_modes[usize::from(n)] =
                        DoMode::from_register(v).ok_or(Exception::IllegalDataValue)?;
                }
                Some(Point::AllDo) if v >> DO_CHANNELS == 0 => plan.all_do = Some(v),
                Some(Point::AllDo) => return Err(Exception::IllegalDataValue),
                _ => return Err(Exception::IllegalDataAddress),
            }
        }
        if plan.settings.pulses.iter().any(|p| p.low == 0 || p.high == 0) {
            return Err(Exception::IllegalDataValue);
        }
        Ok(plan)
    }

    fn read_point(&self, point: Point) -> u16 {
        let settings = self.store.get();
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
            Point::AllDo => (0..pulse::CHANNELS).filter(|n| s.pulse.do_bit(*n)).fold(0, |acc, n| acc | 1 << n),
            Point::Name => MODULE_NAME,
            Point::Version => FIRMWARE_VERSION,
            // "Samples lost since the last read of this register": cleared by the read.
            Point::Diag(d) => DIAGNOSTICS.read(d, status::FRONT_END_FAULT),
        })
    }

    fn write_bits(&self, start: u16, values: &WriteValues<'_>) {
        io::with(self.io, |s| {
            for (i, v) in values.iter().enumerate() {
                let on = v != 0;
                match (decode(Table::Bits, start + i as u16), on) {
                    (Some(Point::Do(n)), _) => s.pulse.set_do(usize::from(n), on),
                    (Some(Point::CounterRun(n)), run) => s.di.set_run(usize::from(n), run),
                    (Some(Point::CounterClear(n)), true) => s.di.clear_counter(usize::from(n)),
                    (Some(Point::Overflow(n)), false) => s.di.clear_overflow(usize::from(n)),
                    (Some(Point::Latch(n)), false) => s.di.clear_latch(usize::from(n)),
                    // Decision: writing 0 to "clear", or 1 to a flag, changes nothing.
                    _ => {}
                }
            }
        });
    }
}

impl<F: NorFlash, R: RawMutex> RegisterMap for Map8350<'_, F, R> {
    fn access(&self, table: Table, addr: u16) -> Access {
        remodaq_protocol::m8350::access(table, addr)
    }

    fn read(&mut self, table: Table, addr: u16) -> u16 {
        decode(table, addr).map_or(0, |point| self.read_point(point))
    }

    fn validate(&self, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        match values.table() {
            Table::Bits => Ok(()),
            Table::Registers => self.plan(start, values).map(|_| ()),
        }
    }

    async fn apply(&mut self, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        if values.table() == Table::Bits {
            self.write_bits(start, values);
            return Ok(());
        }
        let plan = self.plan(start, values)?;
        if plan.settings != *self.store.get() {
            self.store.commit(plan.settings).await.map_err(|e| {
                warn!("8350: settings commit failed: {:?}", e);
                Exception::ServerDeviceFailure
            })?;
        }
        io::with(self.io, |s| {
            s.configure(&plan.settings);
            s.extra = plan.extra;
            for n in 0..pulse::CHANNELS {
                if plan.extra_added & (1 << n) != 0 && plan.extra[n] > 0 {
                    s.pulse.add_pulses(n, plan.extra[n]);
                }
            }
            if let Some(all) = plan.all_do {
                for n in 0..pulse::CHANNELS {
                    s.pulse.set_do(n, all & (1 << n) != 0);
                }
            }
        });
        Ok(())
    }
}

impl<F: NorFlash, R: RawMutex> SettingsAccess for Map8350<'_, F, R> {
    type Settings = Settings;
    fn settings(&self) -> &Settings {
        self.store.get()
    }
    async fn commit(&mut self, settings: Settings) -> Result<(), StoreError> {
        self.store.commit(settings).await
    }
}
