//! Typed, versioned settings on `sequential-storage` over any async `NorFlash` (spec §1.3).
//!
//! A module's settings are one [`Schema`] value stored as one record, so a change of several
//! fields is committed atomically. The record is `MAGIC, schema version, fields...` where each
//! field is `tag, length, bytes`: a newer firmware adds tags, and decoding starts from the
//! factory defaults, so a record written by an older firmware still loads (missing fields keep
//! their defaults) and unknown or malformed fields are skipped.
//!
//! [`SettingsStore::commit`] returns only once the record is in flash (durable on
//! acknowledgement); on failure the value in force stays the old one. A blank store, or one that
//! cannot be read back, gives factory defaults with a log line, and the store keeps working.

use core::ops::Range;

use embedded_storage_async::nor_flash::NorFlash;
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::map::{MapConfig, MapStorage};

/// First byte of every settings record.
const MAGIC: u8 = 0x5D;
/// The map key of the settings record.
const RECORD_KEY: u8 = 1;

/// The map keys of the records a service keeps beside the module's settings, each a [`Schema`]
/// of its own ([`SettingsStore::service_record`]).
pub mod key {
    /// MQTT's settings (services/mqtt, docs/mqtt.md).
    pub const MQTT: u8 = 2;
    /// The CA certificate MQTT's TLS checks the broker against (a raw record: DER).
    pub const MQTT_CA: u8 = 3;
    /// The MQTT broker's user name and password (never shown back).
    pub const MQTT_CREDENTIALS: u8 = 4;
    /// Every service record: what a factory reset removes.
    pub const SERVICES: [u8; 3] = [MQTT, MQTT_CA, MQTT_CREDENTIALS];
}
/// Largest encoded record.
pub const MAX_RECORD: usize = 448;
/// Largest raw record's bytes ([`SettingsStore::commit_raw_record`]: a CA certificate).
pub const MAX_RAW: usize = 768;
/// Work buffer: key + the largest record, rounded up to flash words.
const BUF_LEN: usize = MAX_RAW + 2 + 64;

/// Builds a record's fields.
pub struct RecordWriter<'a> {
    buf: &'a mut [u8],
    len: usize,
    overflow: bool,
}

impl RecordWriter<'_> {
    /// Appends field `tag` with `value` (at most 255 bytes).
    pub fn put(&mut self, tag: u8, value: &[u8]) {
        let end = self.len + 2 + value.len();
        if value.len() > 255 || end > self.buf.len() {
            self.overflow = true;
            return;
        }
        self.buf[self.len] = tag;
        self.buf[self.len + 1] = value.len() as u8;
        self.buf[self.len + 2..end].copy_from_slice(value);
        self.len = end;
    }
    /// Appends a little-endian `u16` field.
    pub fn put_u16(&mut self, tag: u8, value: u16) {
        self.put(tag, &value.to_le_bytes());
    }
    /// Appends a little-endian `u32` field.
    pub fn put_u32(&mut self, tag: u8, value: u32) {
        self.put(tag, &value.to_le_bytes());
    }
}

/// Reads a record's fields.
#[derive(Clone, Copy)]
pub struct RecordReader<'a> {
    fields: &'a [u8],
}

impl<'a> RecordReader<'a> {
    /// A reader over raw field bytes (tests).
    #[doc(hidden)]
    pub fn default_for_tests(fields: &'a [u8]) -> Self {
        Self { fields }
    }

    /// The bytes of field `tag` (the last one if repeated); `None` if absent or truncated.
    pub fn get(&self, tag: u8) -> Option<&'a [u8]> {
        let mut rest = self.fields;
        let mut found = None;
        while let [t, len, tail @ ..] = rest {
            let len = usize::from(*len);
            let value = tail.get(..len)?;
            if *t == tag {
                found = Some(value);
            }
            rest = &tail[len..];
        }
        found
    }
    /// Field `tag` as exactly `N` bytes.
    pub fn array<const N: usize>(&self, tag: u8) -> Option<[u8; N]> {
        self.get(tag)?.try_into().ok()
    }
    /// Field `tag` as a little-endian `u16`.
    pub fn u16(&self, tag: u8) -> Option<u16> {
        self.array(tag).map(u16::from_le_bytes)
    }
    /// Field `tag` as a little-endian `u32`.
    pub fn u32(&self, tag: u8) -> Option<u32> {
        self.array(tag).map(u32::from_le_bytes)
    }
}

/// A module's persisted settings.
pub trait Schema: Clone + PartialEq {
    /// Version written into new records (increase when fields change meaning).
    const VERSION: u8;
    /// Factory defaults.
    fn defaults() -> Self;
    /// What a store that holds something it cannot read loads (corrupted, unreadable, not a
    /// settings record): the factory defaults with the credential locked
    /// (`password::LOCKED`), so that the module fails closed instead of handing itself to
    /// whoever knows the factory password (security review finding 9): Modbus serves, and
    /// administration refuses until a physical factory reset.
    fn unreadable() -> Self;
    /// Writes every field.
    fn encode(&self, w: &mut RecordWriter<'_>);
    /// Starts from `defaults()` and takes every field of `r` it knows and finds valid.
    fn decode(version: u8, r: &RecordReader<'_>) -> Self;
}

/// Encodes `value` into `out`; returns the record length, or `None` if it does not fit.
pub fn encode_record<S: Schema>(value: &S, out: &mut [u8]) -> Option<usize> {
    if out.len() < 2 {
        return None;
    }
    out[0] = MAGIC;
    out[1] = S::VERSION;
    let (_, fields) = out.split_at_mut(2);
    let mut w = RecordWriter { buf: fields, len: 0, overflow: false };
    value.encode(&mut w);
    (!w.overflow).then_some(2 + w.len)
}

/// Decodes a record; `None` if it is not a settings record at all.
pub fn decode_record<S: Schema>(record: &[u8]) -> Option<S> {
    match record {
        [MAGIC, version, fields @ ..] => Some(S::decode(*version, &RecordReader { fields })),
        _ => None,
    }
}

/// Why a commit failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError {
    /// The flash reported an error (or lost power) during the write.
    Flash,
    /// The store found its content corrupted.
    Corrupted,
    /// The record does not fit.
    TooLarge,
    /// The commit budget is spent (flash wear, docs/security.md): nothing written.
    Budget,
}

#[repr(C, align(4))]
struct Buffer([u8; BUF_LEN]);

/// Modbus writes' settings commits allowed in a burst (docs/security.md, "Flash wear").
pub const COMMIT_BURST: u32 = 100;
/// One Modbus write's commit more is allowed every this many ms. With [`ADMIN_REFILL_MS`], the
/// worst rate the budgets allow wears the settings sectors by at most 10 000 erase cycles in
/// 10 years (`modules/8350/tests/wear.rs` measures it).
pub const COMMIT_REFILL_MS: u64 = 180_000;
/// Authenticated changes' commits (network, password, allow-list, web port: discovery and the
/// web console, under any credential, the public factory password included) allowed in a
/// burst: more than a commissioning needs.
pub const ADMIN_BURST: u32 = 20;
/// One authenticated commit more is allowed every this many ms (15 minutes).
pub const ADMIN_REFILL_MS: u64 = 900_000;

/// Which budget a commit draws on (docs/security.md, "Flash wear").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Draw {
    /// A Modbus write: refused when the writes' budget is spent.
    Write,
    /// An authenticated change (discovery, web console): refused when the administration's
    /// budget is spent.
    Admin,
    /// An update's security counters: drawn from the administration's budget but never
    /// refused (each needs an image signed with the update key and a restart; refusing it would
    /// leave the anti-rollback counter behind).
    Counter,
}

/// What a restart carries to the next start: each commit budget's debt (ms until full), so
/// that restarting the module again and again (anyone may, on a module with the factory
/// password) renews nothing. The board keeps its four words where a reset does not clear
/// them ([`crate::board::Board::retained`]); a power-on finds garbage, which the check word
/// refuses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Retained {
    /// The Modbus writes' budget's debt, ms.
    pub writes_ms: u32,
    /// The administration's budget's debt, ms.
    pub admin_ms: u32,
}

const RETAINED_MAGIC: u32 = 0x4255_4447;

/// The stores' budgets as last taken from (full-again times, ms since start), for a restart.
static DEBTS: embassy_sync::blocking_mutex::Mutex<
    embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex,
    core::cell::Cell<(crate::budget::Budget, crate::budget::Budget)>,
> = embassy_sync::blocking_mutex::Mutex::new(core::cell::Cell::new((
    crate::budget::Budget::new(COMMIT_BURST, COMMIT_REFILL_MS),
    crate::budget::Budget::new(ADMIN_BURST, ADMIN_REFILL_MS),
)));

impl Retained {
    /// The budgets' debts now: what a board keeps when it restarts the module.
    pub fn now() -> Self {
        let (writes, admin) = DEBTS.lock(|d| d.get());
        Self::of(writes, admin, embassy_time::Instant::now().as_millis())
    }

    fn of(writes: crate::budget::Budget, admin: crate::budget::Budget, now_ms: u64) -> Self {
        let ms = |b: crate::budget::Budget| u32::try_from(b.debt(now_ms)).unwrap_or(u32::MAX);
        Self { writes_ms: ms(writes), admin_ms: ms(admin) }
    }

    fn check(writes_ms: u32, admin_ms: u32) -> u32 {
        !(RETAINED_MAGIC ^ writes_ms.rotate_left(7) ^ admin_ms.rotate_left(19))
    }

    /// The words a board keeps.
    pub fn to_words(self) -> [u32; 4] {
        [RETAINED_MAGIC, self.writes_ms, self.admin_ms, Self::check(self.writes_ms, self.admin_ms)]
    }

    /// The debts in `words`, if they are what [`Retained::to_words`] made.
    pub fn from_words(words: [u32; 4]) -> Option<Self> {
        let [magic, writes_ms, admin_ms, check] = words;
        (magic == RETAINED_MAGIC && check == Self::check(writes_ms, admin_ms)).then_some(Self { writes_ms, admin_ms })
    }
}

/// Where the settings are, how they load, how they commit.
pub struct SettingsStore<F: NorFlash, S: Schema> {
    map: MapStorage<u8, F, Cache<Uncached, Uncached, Uncached, u8>>,
    buf: Buffer,
    /// The record being written: a service's raw record from [`Self::fill_raw_record`] to its
    /// commit, or a record encoded for a commit. Here rather than in the caller's future, which
    /// every connection task that may commit (ten Modbus slots, the web console's, discovery)
    /// would otherwise hold through the flash write (issue #40: the STM32's RAM).
    scratch: [u8; MAX_RAW + 2],
    current: S,
    /// The settings a commit is writing ([`Self::stage`], [`Self::commit_staged`]), put in force
    /// once durable; here for the same reason as `scratch`.
    staged: S,
    /// The commit budget of Modbus writes.
    writes: crate::budget::Budget,
    /// The commit budget of authenticated changes.
    admin: crate::budget::Budget,
}

impl<F: NorFlash, S: Schema> SettingsStore<F, S> {
    /// Checks a flash range at compile time when used in a `const` block.
    pub const fn config(range: Range<u32>) -> MapConfig<F> {
        MapConfig::new(range)
    }

    /// Opens the store and loads the settings; factory defaults when blank or unreadable.
    pub async fn open(flash: F, config: MapConfig<F>) -> Self {
        let mut store = Self {
            map: MapStorage::new(flash, config, Cache::new_uncached()),
            buf: Buffer([0; BUF_LEN]),
            scratch: [0; MAX_RAW + 2],
            current: S::defaults(),
            staged: S::defaults(),
            // Full, as after a power-on; the start-up sets them for its reset cause (`resume`).
            writes: crate::budget::Budget::new(COMMIT_BURST, COMMIT_REFILL_MS),
            admin: crate::budget::Budget::new(ADMIN_BURST, ADMIN_REFILL_MS),
        };
        store.current = store.load().await;
        store
    }

    /// Sets the commit budgets for a start with this reset cause (docs/security.md, "Flash
    /// wear"): after a power-on, a brown-out or the reset pin (someone at the module), both
    /// are full; after any other reset (a restart, an update, the watchdog) each owes what it
    /// owed before, as `retained` says, or nothing is in either until its first refill when
    /// the board kept nothing.
    pub fn resume(&mut self, cause: crate::diagnostics::ResetCause, retained: Option<Retained>) {
        use crate::budget::Budget;
        use crate::diagnostics::ResetCause;
        let now = embassy_time::Instant::now().as_millis();
        (self.writes, self.admin) = match (cause, retained) {
            (ResetCause::PowerOn | ResetCause::BrownOut | ResetCause::Pin, _) => {
                (Budget::new(COMMIT_BURST, COMMIT_REFILL_MS), Budget::new(ADMIN_BURST, ADMIN_REFILL_MS))
            }
            (_, Some(r)) => (
                Budget::owing(COMMIT_BURST, COMMIT_REFILL_MS, r.writes_ms.into(), now),
                Budget::owing(ADMIN_BURST, ADMIN_REFILL_MS, r.admin_ms.into(), now),
            ),
            (_, None) => (
                Budget::holding(COMMIT_BURST, COMMIT_REFILL_MS, 0, now),
                Budget::holding(ADMIN_BURST, ADMIN_REFILL_MS, 0, now),
            ),
        };
        self.keep_debts();
    }

    /// Takes one commit from `draw`'s budget at `now_ms`; false (nothing taken) when it is
    /// spent.
    pub fn take(&mut self, draw: Draw, now_ms: u64) -> bool {
        let taken = match draw {
            Draw::Write => self.writes.take(now_ms),
            Draw::Admin => self.admin.take(now_ms),
            Draw::Counter => {
                self.admin.draw(now_ms);
                true
            }
        };
        self.keep_debts();
        taken
    }

    /// This store's budgets' debts at `now_ms` (what [`Retained::now`] gives a board for the
    /// store in force).
    pub fn retained(&self, now_ms: u64) -> Retained {
        Retained::of(self.writes, self.admin, now_ms)
    }

    fn keep_debts(&self) {
        DEBTS.lock(|d| d.set((self.writes, self.admin)));
    }

    async fn load(&mut self) -> S {
        /// What the store held: a record (decoded, or `None` when it is not a settings record),
        /// nothing, a corrupted store, or a flash that could not be read.
        enum Held<S> {
            Record(Option<S>),
            Nothing,
            Corrupted,
            Unreadable,
        }
        let held = match self.map.fetch_item::<&[u8]>(&mut self.buf.0, &RECORD_KEY).await {
            Ok(Some(record)) => Held::Record(decode_record::<S>(record)),
            Ok(None) => Held::Nothing,
            Err(sequential_storage::Error::Corrupted { .. }) => Held::Corrupted,
            Err(_) => Held::Unreadable,
        };
        match held {
            Held::Record(Some(value)) => value,
            Held::Record(None) => {
                crate::error!("settings: record not recognised: factory defaults, locked until a factory reset");
                S::unreadable()
            }
            Held::Nothing if self.is_blank().await => {
                crate::info!("settings: store is blank, using factory defaults");
                S::defaults()
            }
            Held::Nothing => {
                // Written, yet no record checks: damaged, or a power cut during the very first
                // commit. Factory defaults would unclaim a module that was claimed.
                crate::error!(
                    "settings: no readable record in a written store: factory defaults, locked until a factory reset"
                );
                S::unreadable()
            }
            Held::Corrupted => {
                // Erased and written again locked: a blank store would load the factory
                // password at the next start.
                crate::error!("settings: store corrupted: erased, factory defaults, locked until a factory reset");
                let locked = S::unreadable();
                if self.map.erase_all().await.is_err() || self.store(locked.clone()).await.is_err() {
                    crate::error!("settings: the corrupted store could not be written again");
                }
                locked
            }
            Held::Unreadable => {
                crate::error!("settings: store unreadable: factory defaults, locked until a factory reset");
                S::unreadable()
            }
        }
    }

    /// Whether every byte of the store reads erased (a new module, or a factory reset's erase).
    async fn is_blank(&mut self) -> bool {
        let range = self.map.flash_range();
        let mut offset = range.start;
        while offset < range.end {
            let n = (range.end - offset).min(BUF_LEN as u32) as usize;
            let chunk = &mut self.buf.0[..n];
            if self.map.flash().read(offset, chunk).await.is_err() || chunk.iter().any(|b| *b != 0xFF) {
                return false;
            }
            offset += n as u32;
        }
        true
    }

    /// The settings in force.
    pub fn get(&self) -> &S {
        &self.current
    }

    /// Commits `value` to flash, then puts it in force. On error the old value stays in force.
    /// (The outcome also sets or clears the diagnostics' settings-store-fault bit.)
    pub fn commit(&mut self, value: S) -> impl core::future::Future<Output = Result<(), StoreError>> + '_ {
        // Staged before the future is made, so that the future holds no copy of `value`.
        self.stage(value);
        self.commit_staged()
    }

    /// Takes `value` for [`Self::commit_staged`]: [`Self::commit`] in two steps, so that a
    /// caller's future holds no copy of the settings while the flash is written.
    pub fn stage(&mut self, value: S) {
        self.staged = value;
    }

    /// Commits the settings [`Self::stage`] took, as [`Self::commit`] does.
    pub async fn commit_staged(&mut self) -> Result<(), StoreError> {
        let result = self.store_staged().await;
        crate::diagnostics::DIAGNOSTICS.committed(&result);
        result
    }

    async fn store(&mut self, value: S) -> Result<(), StoreError> {
        self.stage(value);
        self.store_staged().await
    }

    async fn store_staged(&mut self) -> Result<(), StoreError> {
        let len = encode_record(&self.staged, &mut self.scratch[..MAX_RECORD]).ok_or(StoreError::TooLarge)?;
        Self::store_in(&mut self.map, &mut self.buf, RECORD_KEY, &self.scratch[..len]).await?;
        self.current = self.staged.clone();
        Ok(())
    }

    /// Stores `record` under `key`, durable on return; the store's error in its class.
    async fn store_record(&mut self, key: u8, record: &[u8]) -> Result<(), StoreError> {
        Self::store_in(&mut self.map, &mut self.buf, key, record).await
    }

    async fn store_in(
        map: &mut MapStorage<u8, F, Cache<Uncached, Uncached, Uncached, u8>>,
        buf: &mut Buffer,
        key: u8,
        record: &[u8],
    ) -> Result<(), StoreError> {
        match map.store_item::<&[u8]>(&mut buf.0, &key, &record).await {
            Ok(()) => Ok(()),
            Err(sequential_storage::Error::Corrupted { .. }) => {
                crate::error!("settings: store corrupted during commit");
                Err(StoreError::Corrupted)
            }
            Err(sequential_storage::Error::ItemTooBig | sequential_storage::Error::BufferTooSmall(_)) => {
                Err(StoreError::TooLarge)
            }
            Err(_) => {
                crate::error!("settings: commit failed");
                Err(StoreError::Flash)
            }
        }
    }

    /// A service's record (`key::*`), or its defaults when the store holds none; what a store
    /// that cannot be read, or a record that is not one, gives: [`Schema::unreadable`] (a
    /// service's fails closed: MQTT's is off).
    pub async fn service_record<T: Schema>(&mut self, key: u8) -> T {
        if key == RECORD_KEY {
            return T::unreadable();
        }
        match self.map.fetch_item::<&[u8]>(&mut self.buf.0, &key).await {
            Ok(Some(record)) => decode_record::<T>(record).unwrap_or_else(T::unreadable),
            Ok(None) => T::defaults(),
            Err(_) => {
                crate::error!("settings: a service's record cannot be read: its defaults for unreadable settings");
                T::unreadable()
            }
        }
    }

    /// Commits a service's record (`key::*`), durable on return, as [`Self::commit`] does the
    /// module's settings (the caller draws on the budget first, [`Self::take`]).
    pub async fn commit_service_record<T: Schema>(&mut self, key: u8, value: &T) -> Result<(), StoreError> {
        if key == RECORD_KEY {
            return Err(StoreError::TooLarge);
        }
        let len = encode_record(value, &mut self.scratch[..MAX_RECORD]).ok_or(StoreError::TooLarge)?;
        let result = Self::store_in(&mut self.map, &mut self.buf, key, &self.scratch[..len]).await;
        crate::diagnostics::DIAGNOSTICS.committed(&result);
        result
    }

    /// A service's raw record (`key::*`: bytes of its own format, such as a certificate's DER)
    /// given to `read`: the bytes stored with `version`, or none (nothing stored, another
    /// version, a store that cannot be read).
    pub async fn raw_record<R>(&mut self, key: u8, version: u8, read: impl FnOnce(&[u8]) -> R) -> R {
        match self.map.fetch_item::<&[u8]>(&mut self.buf.0, &key).await {
            Ok(Some([MAGIC, v, bytes @ ..])) if *v == version && key != RECORD_KEY => read(bytes),
            _ => read(&[]),
        }
    }

    /// Prepares a service's raw record: `fill` writes its bytes (at most [`MAX_RAW`]) and says
    /// how many, or `None` when its input was not usable; then [`Self::commit_raw_record`]
    /// commits it, read back by [`Self::raw_record`] with `version`.
    pub fn fill_raw_record(&mut self, version: u8, fill: impl FnOnce(&mut [u8]) -> Option<usize>) -> Option<usize> {
        let (head, body) = self.scratch.split_at_mut(2);
        let len = fill(body).filter(|n| *n <= MAX_RAW)?;
        head.copy_from_slice(&[MAGIC, version]);
        Some(len)
    }

    /// Commits under `key` (`key::*`) the raw record [`Self::fill_raw_record`] prepared with
    /// `len` bytes, durable on return.
    pub async fn commit_raw_record(&mut self, key: u8, len: usize) -> Result<(), StoreError> {
        if key == RECORD_KEY || len > MAX_RAW {
            return Err(StoreError::TooLarge);
        }
        let result = Self::store_in(&mut self.map, &mut self.buf, key, &self.scratch[..2 + len]).await;
        crate::diagnostics::DIAGNOSTICS.committed(&result);
        result
    }

    /// Puts every service's record back to its defaults (a factory reset): an empty record,
    /// which reads as the defaults whatever the service ([`Schema::decode`] starts from them).
    /// (Removing the items would need a flash that takes a second write to a word.)
    pub async fn reset_service_records(&mut self) -> Result<(), StoreError> {
        for key in key::SERVICES {
            self.store_record(key, &[MAGIC, 0]).await?;
        }
        Ok(())
    }

    /// Commits the settings in force changed by `change` (see [`Self::commit`]).
    pub async fn update(&mut self, change: impl FnOnce(&mut S)) -> Result<(), StoreError> {
        let mut value = self.current.clone();
        change(&mut value);
        if value == self.current {
            return Ok(());
        }
        self.commit(value).await
    }

    /// The flash under the store (tests inject faults through it).
    pub fn flash_mut(&mut self) -> &mut F {
        self.map.flash()
    }

    /// Gives the flash back (e.g. to reopen the store after a simulated restart).
    pub fn into_flash(self) -> F {
        self.map.destroy().0
    }
}

/// The firmware update security counters kept in the settings (anti-rollback, docs/update.md):
/// the highest counter of an image this module confirmed, and the counter of the image marked
/// and not yet confirmed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Counter {
    /// Images with a lower counter are refused (`Status::Downgrade`, the update service).
    pub confirmed: u32,
    /// The counter of the image marked for the bootloader: it becomes `confirmed` when that
    /// image confirms itself.
    pub pending: u32,
}

/// The settings tag of the counters.
const TAG_COUNTER: u8 = 9;

impl Counter {
    /// Writes the counters into a settings record.
    pub fn encode(&self, w: &mut RecordWriter<'_>) {
        let mut b = [0u8; 8];
        b[..4].copy_from_slice(&self.confirmed.to_le_bytes());
        b[4..].copy_from_slice(&self.pending.to_le_bytes());
        w.put(TAG_COUNTER, &b);
    }
    /// The counters of a settings record (0, 0 if absent: a record of before counters).
    pub fn decode(r: &RecordReader<'_>) -> Self {
        match r.array::<8>(TAG_COUNTER) {
            Some(b) => Counter {
                confirmed: u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                pending: u32::from_le_bytes([b[4], b[5], b[6], b[7]]),
            },
            None => Counter::default(),
        }
    }
}
