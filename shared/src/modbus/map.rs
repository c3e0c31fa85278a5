//! The register-map abstraction a module implements: which addresses exist, how to read them,
//! how to check a write, and how to apply it. The protocol rules live in [`super::pdu`] only.

use super::Exception;

pub use remodaq_protocol::{Access, Table};

/// The values of a validated write request, still in their wire form (no copy).
#[derive(Clone, Copy, Debug)]
pub struct WriteValues<'a> {
    table: Table,
    data: &'a [u8],
    count: u16,
}

impl<'a> WriteValues<'a> {
    /// Registers as big-endian words (`data.len() == 2 * count`).
    pub fn registers(data: &'a [u8]) -> Self {
        let count = (data.len() / 2) as u16;
        Self { table: Table::Registers, data, count }
    }

    /// `count` bits packed LSB first (`data.len() == ceil(count / 8)`).
    pub fn bits(data: &'a [u8], count: u16) -> Self {
        Self { table: Table::Bits, data, count }
    }

    /// Which table the values are for.
    pub fn table(&self) -> Table {
        self.table
    }

    /// Number of values (registers or bits).
    pub fn len(&self) -> usize {
        usize::from(self.count)
    }

    /// True when there are no values.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Value `i` (a bit reads 0 or 1). Out of range reads 0.
    pub fn get(&self, i: usize) -> u16 {
        match self.table {
            Table::Registers => match (self.data.get(2 * i), self.data.get(2 * i + 1)) {
                (Some(&hi), Some(&lo)) => u16::from_be_bytes([hi, lo]),
                _ => 0,
            },
            Table::Bits => {
                if i >= self.len() {
                    return 0;
                }
                self.data.get(i / 8).map_or(0, |b| u16::from((b >> (i % 8)) & 1))
            }
        }
    }

    /// All values in order.
    pub fn iter(&self) -> impl Iterator<Item = u16> + '_ {
        (0..self.len()).map(|i| self.get(i))
    }

    /// The 32-bit value whose low word is value `i` and high word value `i + 1`
    /// (the RemoDAQ "low word first" order).
    pub fn get_u32_low_first(&self, i: usize) -> u32 {
        u32::from(self.get(i)) | (u32::from(self.get(i + 1)) << 16)
    }
}

/// A module's data model as seen by Modbus.
///
/// The protocol engine calls, for each request: `access` for every address (exception 02 if any
/// is not mapped for that access), then for reads `read` for each address in order, for writes
/// `validate` once with the whole request (exception 03 if the values are unacceptable) and
/// `apply` once (exception 04 if it fails, e.g. the settings store could not commit). `apply`
/// must either apply all of the values or none of them.
#[allow(async_fn_in_trait)]
pub trait RegisterMap {
    /// Whether `addr` of `table` may be read / written.
    fn access(&self, table: Table, addr: u16) -> Access;

    /// Read one value (a bit as 0/1). Only called for readable addresses, after the whole
    /// requested range was checked; may have side effects such as clear-on-read.
    fn read(&mut self, table: Table, addr: u16) -> u16;

    /// Check the values of a write to `start..start + values.len()`, all writable.
    fn validate(&self, start: u16, values: &WriteValues<'_>) -> Result<(), Exception>;

    /// Apply a validated write: all or nothing. Persisted values must be committed to flash
    /// before this returns `Ok` (durable on acknowledgement).
    async fn apply(&mut self, start: u16, values: &WriteValues<'_>) -> Result<(), Exception>;
}
