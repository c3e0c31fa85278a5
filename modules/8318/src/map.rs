//! The 8318 register map (spec §2.1) on the shared Modbus core.

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_protocol::m8318::{decode, Reg, CHANNELS, MODULE_NAME, REG_CJC, REG_STATUS, REG_VALUE};
use remodaq_shared::access;
use remodaq_shared::diagnostics::DIAGNOSTICS;
use remodaq_shared::identity::firmware_version;
use remodaq_shared::modbus::map::{allows_each, read_registers_each};
use remodaq_shared::modbus::{Access, Exception, RegisterMap, Table, WriteValues};
use remodaq_shared::module::{write_update, SettingsAccess, Store};
use remodaq_shared::warn;

use crate::input::InputType;
use crate::settings::{cjc_offset_from_register, cjc_offset_to_register, Settings};
use crate::snapshot::Snapshot;

/// The 8318's Modbus view: the settings in force (the store behind its own lock) and the last
/// acquisition cycle.
pub struct Map8318<'a, F: NorFlash> {
    store: &'a Store<F, Settings>,
    settings: Settings,
    snapshot: Snapshot,
}

impl<'a, F: NorFlash> Map8318<'a, F> {
    /// A map over the store with `settings` in force.
    pub fn new(store: &'a Store<F, Settings>, settings: &Settings) -> Self {
        Self { store, settings: *settings, snapshot: Snapshot::default() }
    }

    /// Publishes one acquisition cycle's values, all at once.
    pub fn publish(&mut self, snapshot: Snapshot) {
        self.snapshot = snapshot;
    }
}

/// The settings after a validated write of `values` at `start`.
fn written(settings: &mut Settings, start: u16, values: &WriteValues<'_>) {
    for (i, v) in values.iter().enumerate() {
        match decode(Table::Registers, start + i as u16) {
            Some(Reg::InputType) => settings.input_type = v as u8,
            Some(Reg::CjcOffset) => settings.cjc_offset = cjc_offset_from_register(v).unwrap_or(settings.cjc_offset),
            Some(Reg::EnableMask) => settings.enable_mask = v as u8,
            Some(Reg::OpenValue) => settings.downscale = v == 1,
            _ => {}
        }
    }
}

impl<F: NorFlash> RegisterMap for Map8318<'_, F> {
    fn access(&self, table: Table, addr: u16) -> Access {
        remodaq_protocol::m8318::access(table, addr)
    }

    fn protects(&self, from: [u8; 4]) -> bool {
        !self.settings.allow.is_empty() && self.settings.allow.allows(from)
    }

    fn admit(&mut self, from: [u8; 4], function: u8) -> Result<(), Exception> {
        access::admit(&self.settings.allow, from, function)
    }

    /// The two runs a poll reads, each of read-only registers, are checked in one go: the
    /// values with the CJC (40001-40009) and the statuses (40225-40232).
    fn allows(&self, table: Table, start: u16, count: u16, write: bool) -> bool {
        let end = u32::from(start) + u32::from(count);
        let polled =
            end <= u32::from(REG_CJC) + 1 || (start >= REG_STATUS && end <= u32::from(REG_STATUS) + CHANNELS as u32);
        (table == Table::Registers && !write && polled) || allows_each(self, table, start, count, write)
    }

    /// The values and the statuses are copied in one go; other runs register by register.
    fn read_registers(&mut self, start: u16, out: &mut [u8]) {
        let (first, words) = (usize::from(start), out.len() / 2);
        let within = |base: u16| first.checked_sub(usize::from(base)).filter(|i| i + words <= CHANNELS);
        let chunks = out.chunks_exact_mut(2);
        if let Some(i) = within(REG_VALUE) {
            for (word, v) in chunks.zip(&self.snapshot.values[i..]) {
                word.copy_from_slice(&v.to_be_bytes());
            }
        } else if let Some(i) = within(REG_STATUS) {
            for (word, s) in chunks.zip(&self.snapshot.status[i..]) {
                word.copy_from_slice(&(*s as u16).to_be_bytes());
            }
        } else {
            read_registers_each(self, start, out);
        }
    }

    fn read(&mut self, table: Table, addr: u16) -> u16 {
        let s = &self.settings;
        match decode(table, addr) {
            Some(Reg::Value(n)) => self.snapshot.values[usize::from(n)],
            Some(Reg::Status(n)) => self.snapshot.status[usize::from(n)] as u16,
            Some(Reg::Cjc) => self.snapshot.cjc as u16,
            Some(Reg::InputType) => u16::from(s.input_type),
            Some(Reg::CjcOffset) => cjc_offset_to_register(s.cjc_offset),
            Some(Reg::EnableMask) => u16::from(s.enable_mask),
            Some(Reg::OpenValue) => u16::from(s.downscale),
            Some(Reg::Name) => MODULE_NAME,
            Some(Reg::Version) => firmware_version(),
            Some(Reg::Diag(d)) => DIAGNOSTICS.read(d, 0),
            None => 0,
        }
    }

    fn validate(&self, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        let ok = values.iter().enumerate().all(|(i, v)| match decode(Table::Registers, start + i as u16) {
            Some(Reg::InputType) => u8::try_from(v).is_ok_and(|t| InputType::from_code(t).is_some()),
            Some(Reg::CjcOffset) => cjc_offset_from_register(v).is_some(),
            Some(Reg::EnableMask) => v <= 0x00FF,
            Some(Reg::OpenValue) => v <= 1,
            _ => false,
        });
        if ok {
            Ok(())
        } else {
            Err(Exception::IllegalDataValue)
        }
    }

    /// Every writable register is persisted: committed without the map's lock.
    async fn write<R: RawMutex>(map: &Mutex<R, Self>, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        let store = map.lock().await.store;
        let change = |s: &mut Settings| {
            written(s, start, values);
            Ok::<(), core::convert::Infallible>(())
        };
        // Within the commit budget (flash wear): beyond it, exception 04 and nothing changes.
        write_update(map, store, change).await.map_err(|e| {
            let remodaq_shared::module::UpdateError::Store(e) = e;
            warn!("8318: settings commit failed: {:?}", e);
            Exception::ServerDeviceFailure
        })
    }
}

impl<F: NorFlash> SettingsAccess for Map8318<'_, F> {
    type Settings = Settings;
    fn settings(&self) -> &Settings {
        &self.settings
    }
    fn committed(&mut self, settings: &Settings) {
        self.settings = *settings;
    }
}
