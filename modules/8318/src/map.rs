//! The 8318 register map (spec §2.1) on the shared Modbus core.

use embedded_storage_async::nor_flash::NorFlash;
use remodaq_protocol::m8318::{decode, Reg};
use remodaq_shared::diagnostics::DIAGNOSTICS;
use remodaq_shared::identity::FIRMWARE_VERSION;
use remodaq_shared::modbus::{Access, Exception, RegisterMap, Table, WriteValues};
use remodaq_shared::module::SettingsAccess;
use remodaq_shared::settings::{SettingsStore, StoreError};
use remodaq_shared::warn;

pub use remodaq_protocol::m8318::{REG_CJC, REG_CJC_OFFSET, REG_ENABLE_MASK, REG_INPUT_TYPE};

use crate::acquisition::Snapshot;
use crate::input::InputType;
use crate::settings::{cjc_offset_from_register, cjc_offset_to_register, Settings};
use crate::MODULE_NAME;

/// The 8318's Modbus view, owning the settings store.
pub struct Map8318<F: NorFlash> {
    store: SettingsStore<F, Settings>,
    snapshot: Snapshot,
}

impl<F: NorFlash> Map8318<F> {
    /// A map over the opened settings store.
    pub fn new(store: SettingsStore<F, Settings>) -> Self {
        Self { store, snapshot: Snapshot::default() }
    }

    /// Publishes one acquisition cycle's values, all at once.
    pub fn publish(&mut self, snapshot: Snapshot) {
        self.snapshot = snapshot;
    }
}

impl<F: NorFlash> RegisterMap for Map8318<F> {
    fn access(&self, table: Table, addr: u16) -> Access {
        remodaq_protocol::m8318::access(table, addr)
    }

    fn read(&mut self, table: Table, addr: u16) -> u16 {
        let s = self.store.get();
        match decode(table, addr) {
            Some(Reg::Value(n)) => self.snapshot.values[usize::from(n)],
            Some(Reg::Cjc) => self.snapshot.cjc as u16,
            Some(Reg::InputType) => u16::from(s.input_type),
            Some(Reg::CjcOffset) => cjc_offset_to_register(s.cjc_offset),
            Some(Reg::EnableMask) => u16::from(s.enable_mask),
            Some(Reg::Name) => MODULE_NAME,
            Some(Reg::Version) => FIRMWARE_VERSION,
            Some(Reg::Diag(d)) => DIAGNOSTICS.read(d, 0),
            None => 0,
        }
    }

    fn validate(&self, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        let ok = values.iter().enumerate().all(|(i, v)| match decode(Table::Registers, start + i as u16) {
            Some(Reg::InputType) => u8::try_from(v).is_ok_and(|t| InputType::from_code(t).is_some()),
            Some(Reg::CjcOffset) => cjc_offset_from_register(v).is_some(),
            Some(Reg::EnableMask) => v <= 0x00FF,
            _ => false,
        });
        if ok {
            Ok(())
        } else {
            Err(Exception::IllegalDataValue)
        }
    }

    async fn apply(&mut self, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        let result = self
            .store
            .update(|s| {
                for (i, v) in values.iter().enumerate() {
                    match decode(Table::Registers, start + i as u16) {
                        Some(Reg::InputType) => s.input_type = v as u8,
                        Some(Reg::CjcOffset) => s.cjc_offset = cjc_offset_from_register(v).unwrap_or(s.cjc_offset),
                        Some(Reg::EnableMask) => s.enable_mask = v as u8,
                        _ => {}
                    }
                }
            })
            .await;
        result.map_err(|e| {
            warn!("8318: settings commit failed: {:?}", e);
            Exception::ServerDeviceFailure
        })
    }
}

impl<F: NorFlash> SettingsAccess for Map8318<F> {
    type Settings = Settings;
    fn settings(&self) -> &Settings {
        self.store.get()
    }
    async fn commit(&mut self, settings: Settings) -> Result<(), StoreError> {
        self.store.commit(settings).await
    }
}
