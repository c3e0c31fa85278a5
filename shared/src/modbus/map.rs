//! The register-map abstraction a module implements: which addresses exist, how to read them,
//! how to check a write, and how to apply it. The protocol rules live in [`super::pdu`] only.

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;

use super::exception::Exception;

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

    /// The values in their wire form: big-endian words, or bits packed LSB first.
    pub fn bytes(&self) -> &'a [u8] {
        self.data
    }

    /// The bits of a bit write, in order, as booleans.
    pub fn flags(&self) -> impl Iterator<Item = bool> + '_ {
        (0..self.len()).map(|i| self.data.get(i / 8).is_some_and(|b| b >> (i % 8) & 1 != 0))
    }

    /// The 32-bit value whose low word is value `i` and high word value `i + 1`
    /// (the RemoDAQ "low word first" order).
    pub fn get_u32_low_first(&self, i: usize) -> u32 {
        u32::from(self.get(i)) | (u32::from(self.get(i + 1)) << 16)
    }
}

/// A module's data model as seen by Modbus.
///
/// The protocol engine calls, for each request: `admit` with the client's address and the
/// function code (a module's access rule and host watchdog), `allows` once for the whole run of addresses
/// (exception 02 if any is not mapped for that access), then for reads `read_registers` or
/// `read_bits` once for the run, for writes `validate` once with the whole request (exception
/// 03 if the values are unacceptable) and `apply` once (exception 04 if it fails, e.g. the
/// settings store could not commit). `apply` must either apply all of the values or none of
/// them. The run methods have defaults built on `access` and `read`, one address at a time; a
/// map that keeps its values in arrays answers a run in one go.
#[allow(async_fn_in_trait)]
pub trait RegisterMap {
    /// Whether `addr` of `table` may be read / written.
    fn access(&self, table: Table, addr: u16) -> Access;

    /// Read one value (a bit as 0/1). Only called for readable addresses, after the whole
    /// requested range was checked; may have side effects such as clear-on-read.
    fn read(&mut self, table: Table, addr: u16) -> u16;

    /// Reads one value as [`RegisterMap::read`] does, without its side effects: no flag cleared
    /// by the read. The web console's reads (docs/web.md: a GET changes nothing). The default
    /// is [`RegisterMap::read`], for a map whose reads have no side effects.
    fn observe(&mut self, table: Table, addr: u16) -> u16 {
        self.read(table, addr)
    }

    /// Registers `start..start + out.len()` (inside the 16-bit space, readable) as
    /// [`RegisterMap::observe`] gives them, in one snapshot where the values are kept together
    /// (a 32-bit counter's two words, which the I/O may change between two single reads). The
    /// default: one at a time.
    fn observe_registers(&mut self, start: u16, out: &mut [u16]) {
        observe_registers_each(self, start, out)
    }

    /// Check the values of a write to `start..start + values.len()`, all writable.
    fn validate(&self, start: u16, values: &WriteValues<'_>) -> Result<(), Exception>;

    /// Applies a validated write at once, under the lock the checks ran under, when it only
    /// touches RAM (an output, a counter's run flag): `Some` with the outcome, all or nothing.
    /// `None` when the write has to persist: the engine then releases the lock and calls
    /// [`RegisterMap::write`]. The default: `None` for every write.
    fn write_now(&mut self, start: u16, values: &WriteValues<'_>) -> Option<Result<(), Exception>> {
        let _ = (start, values);
        None
    }

    /// Apply a validated write: all or nothing. Persisted values must be committed to flash
    /// before this returns `Ok` (durable on acknowledgement). Called by the default
    /// [`RegisterMap::write`]; a map that overrides `write` need not implement it (the default
    /// refuses with exception 04).
    async fn apply(&mut self, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        let _ = (start, values);
        Err(Exception::ServerDeviceFailure)
    }

    /// Carries out a validated write on the map behind its lock, as the connection server
    /// does. The default applies it under the lock; a map whose writes commit to flash
    /// overrides this to commit without holding the lock, so reads go on meanwhile.
    async fn write<R: RawMutex>(map: &Mutex<R, Self>, start: u16, values: &WriteValues<'_>) -> Result<(), Exception>
    where
        Self: Sized,
    {
        map.lock().await.apply(start, values).await
    }

    /// Whether the request with `function` from the client at `from` (IPv4; 0.0.0.0 when
    /// unknown) is served; called first, for every request. The default serves everything.
    fn admit(&mut self, from: [u8; 4], function: u8) -> Result<(), Exception> {
        let _ = (from, function);
        Ok(())
    }

    /// Whether a write allow-list is set and admits the client at `from`: such a client is never
    /// closed to make room for one the list does not admit. The default protects nobody.
    fn protects(&self, from: [u8; 4]) -> bool {
        let _ = from;
        false
    }

    /// Whether every address of `start..start + count` (inside the 16-bit space, checked by the
    /// engine) allows reading, or writing when `write`.
    fn allows(&self, table: Table, start: u16, count: u16, write: bool) -> bool {
        allows_each(self, table, start, count, write)
    }

    /// Reads registers `start..` into `out` as big-endian words (`out.len()` is even), after
    /// `allows` accepted the run.
    fn read_registers(&mut self, start: u16, out: &mut [u8]) {
        read_registers_each(self, start, out)
    }

    /// Reads `count` bits from `start` into `out`, packed LSB first (`out` is zeroed and holds
    /// `ceil(count / 8)` bytes), after `allows` accepted the run.
    fn read_bits(&mut self, start: u16, count: u16, out: &mut [u8]) {
        read_bits_each(self, start, count, out)
    }
}

/// [`RegisterMap::allows`] one address at a time, through [`RegisterMap::access`]: the default,
/// and the fallback of a map that answers some runs in one go.
pub fn allows_each<M: RegisterMap + ?Sized>(map: &M, table: Table, start: u16, count: u16, write: bool) -> bool {
    // `start + i` stays within 16 bits: the engine checked `start + count <= 0x1_0000`.
    (0..count).all(|i| {
        let access = map.access(table, start + i);
        if write {
            access.writable()
        } else {
            access.readable()
        }
    })
}

/// [`RegisterMap::observe_registers`] one register at a time, through [`RegisterMap::observe`].
pub fn observe_registers_each<M: RegisterMap + ?Sized>(map: &mut M, start: u16, out: &mut [u16]) {
    for (i, v) in out.iter_mut().enumerate() {
        *v = map.observe(Table::Registers, start.wrapping_add(i as u16));
    }
}

/// [`RegisterMap::read_registers`] one register at a time, through [`RegisterMap::read`].
pub fn read_registers_each<M: RegisterMap + ?Sized>(map: &mut M, start: u16, out: &mut [u8]) {
    for (i, word) in out.chunks_exact_mut(2).enumerate() {
        word.copy_from_slice(&map.read(Table::Registers, start + i as u16).to_be_bytes());
    }
}

/// [`RegisterMap::read_bits`] one bit at a time, through [`RegisterMap::read`].
pub fn read_bits_each<M: RegisterMap + ?Sized>(map: &mut M, start: u16, count: u16, out: &mut [u8]) {
    for i in 0..count {
        if map.read(Table::Bits, start + i) != 0 {
            out[usize::from(i / 8)] |= 1 << (i % 8);
        }
    }
}
