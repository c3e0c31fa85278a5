//! The 8318 register map (spec §2.1) on the shared Modbus core.

use embedded_storage_async::nor_flash::NorFlash;
use remodaq_shared::modbus::{Access, Exception, RegisterMap, Table, WriteValues};
use remodaq_shared::module::SettingsAccess;
use remodaq_shared::settings::{SettingsStore, StoreError};
use remodaq_shared::{identity, warn};

use crate::acquisition::{Snapshot, CHANNELS};
use crate::input::InputType;
use crate::settings::{cjc_offset_from_register, cjc_offset_to_register, Settings};
use crate::MODULE_NAME;

/// 40009: cold-junction temperature.
pub const REG_CJC: u16 = 0x0008;
/// 40201: input type code.
pub const REG_INPUT_TYPE: u16 = 0x00C8;
/// 40216: CJC offset.
pub const REG_CJC_OFFSET: u16 = 0x00D7;
/// 40221: channel enable mask.
pub const REG_ENABLE_MASK: u16 = 0x00DC;

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
        match (table, addr) {
            (Table::Bits, _) => Access::None,
            (Table::Registers, 0..=REG_CJC) => Access::Read,
            (Table::Registers, identity::REG_NAME | identity::REG_VERSION) => Access::Read,
            (Table::Registers, REG_INPUT_TYPE | REG_CJC_OFFSET | REG_ENABLE_MASK) => Access::ReadWrite,
            (Table::Registers, _) => Access::None,
        }
    }

    fn read(&mut self, _table: Table, addr: u16) -> u16 {
        let s = self.store.get();
        match addr {
            a if usize::from(a) < CHANNELS => self.snapshot.values[usize::from(a)],
            REG_CJC => self.snapshot.cjc as u16,
            REG_INPUT_TYPE => u16::from(s.input_type),
            REG_CJC_OFFSET => cjc_offset_to_register(s.cjc_offset),
            REG_ENABLE_MASK => u16::from(s.enable_mask),
            _ => identity::read(MODULE_NAME, addr).unwrap_or(0),
        }
    }

    fn validate(&self, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        let ok = values.iter().enumerate().all(|(i, v)| match start + i as u16 {
            REG_INPUT_TYPE => u8::try_from(v).is_ok_and(|t| InputType::from_code(t).is_some()),
            REG_CJC_OFFSET => cjc_offset_from_register(v).is_some(),
            REG_ENABLE_MASK => v <= 0x00FF,
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
                    match start + i as u16 {
                        REG_INPUT_TYPE => s.input_type = v as u8,
                        REG_CJC_OFFSET => s.cjc_offset = cjc_offset_from_register(v).unwrap_or(s.cjc_offset),
                        REG_ENABLE_MASK => s.enable_mask = v as u8,
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
