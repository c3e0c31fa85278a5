//! The 8350 register map (spec §3.1-3.2) on the shared Modbus core.
//!
//! Writes are planned on a copy first (the new settings, the extra pulses, the all-DO value),
//! which is both the validation and what gets applied: persisted settings are committed to
//! flash before anything reaches the outputs, so a failed commit (exception 04) changes nothing.

use embassy_sync::blocking_mutex::raw::RawMutex;
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_shared::modbus::{Access, Exception, RegisterMap, Table, WriteValues};
use remodaq_shared::module::SettingsAccess;
use remodaq_shared::settings::{SettingsStore, StoreError};
use remodaq_shared::{identity, warn};

use crate::di::{self, DiMode};
use crate::io::{self, IoCell};
use crate::pulse::{self, DoMode};
use crate::settings::Settings;
use crate::MODULE_NAME;

/// 0X: DI n state.
pub const BIT_DI: u16 = 0x00;
/// 0X: DO n.
pub const BIT_DO: u16 = 0x10;
/// 0X: DI n counter run / clear / overflow / latch at `BIT_COUNTER + 4n + 0..3`.
pub const BIT_COUNTER: u16 = 0x20;
/// 4X: DI n counter, 32-bit low word first.
pub const REG_COUNTER: u16 = 0x00;
/// 4X: DO n pulse low width, high width, count, extra pulses (32-bit, 12 registers each).
pub const REG_PULSE: u16 = 0x18;
/// 4X: DI n mode.
pub const REG_DI_MODE: u16 = 0x100;
/// 4X: DO n mode.
pub const REG_DO_MODE: u16 = 0x110;
/// 4X: all DI.
pub const REG_ALL_DI: u16 = 0x12C;
/// 4X: all DO.
pub const REG_ALL_DO: u16 = 0x12E;

const DI: u16 = di::CHANNELS as u16;
const DO: u16 = pulse::CHANNELS as u16;
/// The pulse registers: 4 fields x 6 outputs x 2 words.
const PULSE_WORDS: u16 = 4 * DO * 2;

/// Which 32-bit pulse field a register belongs to: (field, output, high word).
fn pulse_field(addr: u16) -> (usize, usize, bool) {
    let i = addr - REG_PULSE;
    (usize::from(i / (2 * DO)), usize::from(i % (2 * DO) / 2), i % 2 == 1)
}

fn set_word(value: &mut u32, high: bool, word: u16) {
    *value = if high { (*value & 0xFFFF) | u32::from(word) << 16 } else { (*value & 0xFFFF_0000) | u32::from(word) };
}

fn word(value: u32, high: bool) -> u16 {
    if high {
        (value >> 16) as u16
    } else {
        value as u16
    }
}

/// A register write, planned.
struct Plan {
    settings: Settings,
    extra: [u32; pulse::CHANNELS],
    extra_written: u8,
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
            Plan { settings: *self.store.get(), extra: io::with(self.io, |s| s.extra), extra_written: 0, all_do: None };
        for (i, v) in values.iter().enumerate() {
            let addr = start + i as u16;
            match addr {
                a if (REG_PULSE..REG_PULSE + PULSE_WORDS).contains(&a) => {
                    let (field, n, high) = pulse_field(a);
                    let p = &mut plan.settings.pulses[n];
                    match field {
                        0 => set_word(&mut p.low, high, v),
                        1 => set_word(&mut p.high, high, v),
                        2 => set_word(&mut p.count, high, v),
                        _ => {
                            set_word(&mut plan.extra[n], high, v);
                            plan.extra_written |= 1 << n;
                        }
                    }
                }
                a if (REG_DI_MODE..REG_DI_MODE + DI).contains(&a) => {
                    plan.settings.di_modes[usize::from(a - REG_DI_MODE)] =
                        DiMode::from_register(v).ok_or(Exception::IllegalDataValue)?;
                }
                a if (REG_DO_MODE..REG_DO_MODE + DO).contains(&a) => {
                    plan.settings.do_modes[usize::from(a - REG_DO_MODE)] =
                        DoMode::from_register(v).ok_or(Exception::IllegalDataValue)?;
                }
                REG_ALL_DO if v >> DO == 0 => plan.all_do = Some(v),
                REG_ALL_DO => return Err(Exception::IllegalDataValue),
                _ => return Err(Exception::IllegalDataAddress),
            }
        }
        if plan.settings.pulses.iter().any(|p| p.low == 0 || p.high == 0) {
            return Err(Exception::IllegalDataValue);
        }
        Ok(plan)
    }

    fn read_bit(&self, addr: u16) -> u16 {
        io::with(self.io, |s| {
            let on = match addr {
                a if a < BIT_DI + DI => s.di.state() >> a & 1 != 0,
                a if (BIT_DO..BIT_DO + DO).contains(&a) => s.pulse.do_bit(usize::from(a - BIT_DO)),
                a => {
                    let n = usize::from((a - BIT_COUNTER) / 4);
                    match (a - BIT_COUNTER) % 4 {
                        0 => s.di.run(n),
                        1 => false,
                        2 => s.di.take_overflow(n),
                        _ => s.di.take_latch(n),
                    }
                }
            };
            u16::from(on)
        })
    }

    fn read_register(&self, addr: u16) -> u16 {
        let settings = self.store.get();
        match addr {
            a if a < REG_COUNTER + 2 * DI => {
                let value = io::with(self.io, |s| s.di.counter_value(usize::from(a / 2)));
                word(value, a % 2 == 1)
            }
            a if (REG_PULSE..REG_PULSE + PULSE_WORDS).contains(&a) => {
                let (field, n, high) = pulse_field(a);
                let p = settings.pulses[n];
                let value = match field {
                    0 => p.low,
                    1 => p.high,
                    2 => p.count,
                    _ => io::with(self.io, |s| s.extra[n]),
                };
                word(value, high)
            }
            a if (REG_DI_MODE..REG_DI_MODE + DI).contains(&a) => settings.di_modes[usize::from(a - REG_DI_MODE)] as u16,
            a if (REG_DO_MODE..REG_DO_MODE + DO).contains(&a) => settings.do_modes[usize::from(a - REG_DO_MODE)] as u16,
            REG_ALL_DI => io::with(self.io, |s| s.di.state()),
            REG_ALL_DO => io::with(self.io, |s| {
                (0..pulse::CHANNELS).filter(|n| s.pulse.do_bit(*n)).fold(0, |acc, n| acc | 1 << n)
            }),
            a => identity::read(MODULE_NAME, a).unwrap_or(0),
        }
    }

    fn write_bits(&self, start: u16, values: &WriteValues<'_>) {
        io::with(self.io, |s| {
            for (i, v) in values.iter().enumerate() {
                let addr = start + i as u16;
                let on = v != 0;
                if (BIT_DO..BIT_DO + DO).contains(&addr) {
                    s.pulse.set_do(usize::from(addr - BIT_DO), on);
                    continue;
                }
                let n = usize::from((addr - BIT_COUNTER) / 4);
                match ((addr - BIT_COUNTER) % 4, on) {
                    (0, run) => s.di.set_run(n, run),
                    (1, true) => s.di.clear_counter(n),
                    (2, false) => s.di.clear_overflow(n),
                    (3, false) => s.di.clear_latch(n),
                    // Decision: writing 0 to "clear", or 1 to a flag, changes nothing.
                    _ => {}
                }
            }
        });
    }
}

impl<F: NorFlash, R: RawMutex> RegisterMap for Map8350<'_, F, R> {
    fn access(&self, table: Table, addr: u16) -> Access {
        match (table, addr) {
            (Table::Bits, a) if a < BIT_DI + DI => Access::Read,
            (Table::Bits, a) if (BIT_DO..BIT_DO + DO).contains(&a) => Access::ReadWrite,
            (Table::Bits, a) if (BIT_COUNTER..BIT_COUNTER + 4 * DI).contains(&a) => Access::ReadWrite,
            (Table::Registers, a) if a < REG_COUNTER + 2 * DI => Access::Read,
            (Table::Registers, a) if (REG_PULSE..REG_PULSE + PULSE_WORDS).contains(&a) => Access::ReadWrite,
            (Table::Registers, identity::REG_NAME | identity::REG_VERSION | REG_ALL_DI) => Access::Read,
            (Table::Registers, a) if (REG_DI_MODE..REG_DI_MODE + DI).contains(&a) => Access::ReadWrite,
            (Table::Registers, a) if (REG_DO_MODE..REG_DO_MODE + DO).contains(&a) => Access::ReadWrite,
            (Table::Registers, REG_ALL_DO) => Access::ReadWrite,
            _ => Access::None,
        }
    }

    fn read(&mut self, table: Table, addr: u16) -> u16 {
        match table {
            Table::Bits => self.read_bit(addr),
            Table::Registers => self.read_register(addr),
        }
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
                if plan.extra_written & (1 << n) != 0 && plan.extra[n] > 0 {
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
