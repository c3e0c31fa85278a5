//! The 8350 register map (spec §3.1-3.2) on the shared Modbus core. This foundation maps the
//! identity registers; the DI/DO bits and registers join with the counter and pulse engines.

use embedded_storage_async::nor_flash::NorFlash;
use remodaq_shared::identity;
use remodaq_shared::modbus::{Access, Exception, RegisterMap, Table, WriteValues};
use remodaq_shared::settings::SettingsStore;

use crate::settings::Settings;
use crate::MODULE_NAME;

/// The 8350's Modbus view, owning the settings store.
pub struct Map8350<F: NorFlash> {
    store: SettingsStore<F, Settings>,
}

impl<F: NorFlash> Map8350<F> {
    /// A map over the opened settings store.
    pub fn new(store: SettingsStore<F, Settings>) -> Self {
        Self { store }
    }

    /// The settings in force.
    pub fn settings(&self) -> &Settings {
        self.store.get()
    }
}

impl<F: NorFlash> RegisterMap for Map8350<F> {
    fn access(&self, table: Table, addr: u16) -> Access {
        match (table, addr) {
            // Decision (spec §3.2): the version register is read only, writes answer 02.
            (Table::Registers, identity::REG_NAME | identity::REG_VERSION) => Access::Read,
            _ => Access::None,
        }
    }

    fn read(&mut self, _table: Table, addr: u16) -> u16 {
        identity::read(MODULE_NAME, addr).unwrap_or(0)
    }

    fn validate(&self, _start: u16, _values: &WriteValues<'_>) -> Result<(), Exception> {
        // No writable address yet: `access` already refused every write.
        Err(Exception::IllegalDataAddress)
    }

    async fn apply(&mut self, _start: u16, _values: &WriteValues<'_>) -> Result<(), Exception> {
        Err(Exception::IllegalDataAddress)
    }
}
