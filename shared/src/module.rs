//! What every module's settings and register map offer to the common services (network
//! configuration and discovery): the network settings and the configuration password.

use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, RawMutex};
use embassy_sync::mutex::Mutex;
use embedded_storage_async::nor_flash::NorFlash;

use crate::net::NetConfig;
use crate::password::Credential;
use crate::protocol::access::AllowList;
use crate::settings::{Schema, SettingsStore, StoreError};

/// Settings present in both modules.
pub trait CommonSettings: Schema + Copy {
    /// The stored network settings (in force after the next start).
    fn net(&self) -> NetConfig;
    /// Changes the stored network settings.
    fn set_net(&mut self, net: NetConfig);
    /// The configuration password's credential.
    fn password(&self) -> Credential;
    /// Changes the configuration password's credential.
    fn set_password(&mut self, credential: Credential);
    /// The Modbus write allow-list (extensions §4).
    fn allow_list(&self) -> AllowList;
    /// Changes the Modbus write allow-list.
    fn set_allow_list(&mut self, list: AllowList);
    /// The web console's TCP port (in force after the next start).
    fn http_port(&self) -> u16;
    /// Changes it.
    fn set_http_port(&mut self, port: u16);
    /// The firmware update security counters (anti-rollback).
    fn update_counter(&self) -> crate::settings::Counter;
    /// Changes them.
    fn set_update_counter(&mut self, counter: crate::settings::Counter);
}

/// The settings store behind its own lock, shared by the register map (Modbus writes) and the
/// discovery service. A commit holds this lock and never the register map's, so Modbus reads
/// go on while the flash is written (extensions §4). Lock order: the store, then the map.
pub type Store<F, S> = Mutex<CriticalSectionRawMutex, SettingsStore<F, S>>;

/// The settings in force, as a module's register map keeps them (a copy of the store's, so
/// that reading them never waits for a commit).
pub trait SettingsAccess {
    /// The module's settings.
    type Settings: CommonSettings;
    /// The settings in force.
    fn settings(&self) -> &Self::Settings;
    /// Puts settings just committed in force.
    fn committed(&mut self, settings: &Self::Settings);
}

pub use crate::settings::{Draw, ADMIN_BURST, ADMIN_REFILL_MS, COMMIT_BURST, COMMIT_REFILL_MS};

/// Why [`update`] changed nothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpdateError<E> {
    /// The change refused the settings.
    Refused(E),
    /// The store could not commit; the old settings stay in force.
    Store(StoreError),
}

/// Applies `change` to the latest settings and commits them (when they changed) holding the
/// store's lock only, then puts them in force in `map`. Returns what `change` returned. For
/// authenticated changes (discovery, the web console): a commit beyond the administration's
/// commit budget is refused, whatever the credential (flash wear, docs/security.md). Modbus
/// writes go through [`write_update`].
pub async fn update<R, A, F, T, E>(
    map: &Mutex<R, A>,
    store: &Store<F, A::Settings>,
    change: impl FnOnce(&mut A::Settings) -> Result<T, E>,
) -> Result<T, UpdateError<E>>
where
    R: RawMutex,
    A: SettingsAccess,
    F: NorFlash,
{
    commit_within(map, store, change, Draw::Admin).await
}

/// [`update`] for a Modbus write: a commit beyond the writes' commit budget is refused (flash
/// wear, docs/security.md). Authenticated changes draw on a budget of their own, so a Modbus
/// writer cannot keep the administrator from changing the password, the allow-list or the
/// firmware.
pub async fn write_update<R, A, F, T, E>(
    map: &Mutex<R, A>,
    store: &Store<F, A::Settings>,
    change: impl FnOnce(&mut A::Settings) -> Result<T, E>,
) -> Result<T, UpdateError<E>>
where
    R: RawMutex,
    A: SettingsAccess,
    F: NorFlash,
{
    commit_within(map, store, change, Draw::Write).await
}

async fn commit_within<R, A, F, T, E>(
    map: &Mutex<R, A>,
    store: &Store<F, A::Settings>,
    change: impl FnOnce(&mut A::Settings) -> Result<T, E>,
    draw: Draw,
) -> Result<T, UpdateError<E>>
where
    R: RawMutex,
    A: SettingsAccess,
    F: NorFlash,
{
    let mut store = store.lock().await;
    let (out, staged) = stage(&mut store, change, draw)?;
    if !staged {
        return Ok(out);
    }
    // From the flash write to the map's update, a connection's deadline waits (finding 15c:
    // a request dropped in between left the flash with the change and RAM without it).
    let _under_way = CommitUnderWay::begin();
    store.commit_staged().await.map_err(UpdateError::Store)?;
    // The settings committed are the store's now. Uncontended (the map's lock is never held
    // across an await), taken without a wait.
    match map.try_lock() {
        Ok(mut map) => map.committed(store.get()),
        Err(_) => map.lock().await.committed(store.get()),
    }
    Ok(out)
}

/// The first half of [`commit_within`], without an await: `change` applied to a copy of the
/// settings in force, and the result handed to the store (`SettingsStore::stage`) when it
/// changes them, drawn from `draw`'s budget; with whether it did. In a function of its own, so
/// that the copy is in this function's frame while it runs, neither in the future of
/// [`commit_within`] (which every connection task that may commit holds through the flash write:
/// issue #40, the STM32's RAM) nor in the poll frame of the task it is inlined into.
#[inline(never)]
fn stage<F, S, T, E>(
    store: &mut SettingsStore<F, S>,
    change: impl FnOnce(&mut S) -> Result<T, E>,
    draw: Draw,
) -> Result<(T, bool), UpdateError<E>>
where
    F: NorFlash,
    S: Schema + Copy,
{
    let mut settings = *store.get();
    let out = change(&mut settings).map_err(UpdateError::Refused)?;
    if settings == *store.get() {
        // A change that changes nothing never reaches the flash.
        return Ok((out, false));
    }
    // A write beyond the budget neither.
    take_budget(store, draw).map_err(UpdateError::Store)?;
    store.stage(settings);
    Ok((out, true))
}

/// One commit from `draw`'s budget, or [`StoreError::Budget`] when it is spent (logged and
/// counted in the security events).
fn take_budget<F: NorFlash, S: Schema>(store: &mut SettingsStore<F, S>, draw: Draw) -> Result<(), StoreError> {
    if store.take(draw, embassy_time::Instant::now().as_millis()) {
        return Ok(());
    }
    crate::warn!("settings: commit budget spent, change refused");
    crate::diagnostics::DIAGNOSTICS.security(crate::diagnostics::Security::WriteBudgetRefusal, [0; 4]);
    Err(StoreError::Budget)
}

/// Commits a service's record (`settings::key::*`: MQTT's settings) as [`commit_change`] commits
/// the module's: nothing when it does not change, drawn from the administration's budget
/// (refused with [`StoreError::Budget`] when spent), a connection's deadline waiting for it;
/// then the service is told (MQTT: [`crate::mqtt::CHANGED`]).
pub async fn commit_service_record<F, S, T>(store: &Store<F, S>, key: u8, value: &T) -> Result<(), StoreError>
where
    F: NorFlash,
    S: Schema,
    T: Schema,
{
    let mut store = store.lock().await;
    if store.service_record::<T>(key).await == *value {
        return Ok(());
    }
    take_budget(&mut store, Draw::Admin)?;
    let _under_way = CommitUnderWay::begin();
    store.commit_service_record(key, value).await?;
    changed(key);
    Ok(())
}

/// Commits a service's raw record (`settings::key::MQTT_CA`) as [`commit_service_record`]
/// commits a record: `fill` writes its bytes (`SettingsStore::fill_raw_record`; `None`: not
/// usable, [`StoreError::TooLarge`] and nothing drawn), drawn from the administration's budget,
/// and the service told.
pub async fn commit_raw_record<F, S>(
    store: &Store<F, S>,
    key: u8,
    version: u8,
    fill: impl FnOnce(&mut [u8]) -> Option<usize>,
) -> Result<(), StoreError>
where
    F: NorFlash,
    S: Schema,
{
    let mut store = store.lock().await;
    let len = store.fill_raw_record(version, fill).ok_or(StoreError::TooLarge)?;
    take_budget(&mut store, Draw::Admin)?;
    let _under_way = CommitUnderWay::begin();
    store.commit_raw_record(key, len).await?;
    changed(key);
    Ok(())
}

/// Tells the service whose record `key` was committed.
fn changed(key: u8) {
    use crate::settings::key;
    if [key::MQTT, key::MQTT_CA, key::MQTT_CREDENTIALS].contains(&key) {
        crate::mqtt::CHANGED.signal(());
    }
}

/// The settings a physical factory reset stores: every one back to its factory default but the
/// update counters, kept (security review finding 11b: a reset to counter 0 let whoever claimed
/// the module next install any older signed image). A store that could not be read has
/// counters 0 anyway.
pub fn factory_reset<S: CommonSettings>(current: &S) -> S {
    let mut reset = S::defaults();
    reset.set_update_counter(current.update_counter());
    reset
}

/// Commits under way: each from its flash write to the map's update ([`CommitUnderWay`]).
static COMMITS_UNDER_WAY: core::sync::atomic::AtomicU8 = core::sync::atomic::AtomicU8::new(0);

/// Whether a settings commit is under way: between its flash write and the register map's
/// update. A service that drops a request on a deadline (the web console's connections) waits
/// for this to end first, so that the flash and the map never disagree (finding 15c).
pub fn commit_under_way() -> bool {
    COMMITS_UNDER_WAY.load(core::sync::atomic::Ordering::Acquire) != 0
}

/// One commit under way, for as long as it lives (a commit dropped anyway ends it too).
struct CommitUnderWay;

impl CommitUnderWay {
    fn begin() -> Self {
        COMMITS_UNDER_WAY.fetch_add(1, core::sync::atomic::Ordering::AcqRel);
        Self
    }
}

impl Drop for CommitUnderWay {
    fn drop(&mut self) {
        COMMITS_UNDER_WAY.fetch_sub(1, core::sync::atomic::Ordering::AcqRel);
    }
}

/// Implements [`CommonSettings`] for a settings struct with the fields `net: NetConfig`,
/// `password: Credential`, `allow: AllowList`, `http_port: u16` and `update: settings::Counter`.
#[macro_export]
macro_rules! impl_common_settings {
    ($settings:ty) => {
        impl $crate::module::CommonSettings for $settings {
            fn net(&self) -> $crate::net::NetConfig {
                self.net
            }
            fn set_net(&mut self, net: $crate::net::NetConfig) {
                self.net = net;
            }
            fn password(&self) -> $crate::password::Credential {
                self.password
            }
            fn set_password(&mut self, credential: $crate::password::Credential) {
                self.password = credential;
            }
            fn allow_list(&self) -> $crate::protocol::access::AllowList {
                self.allow
            }
            fn set_allow_list(&mut self, list: $crate::protocol::access::AllowList) {
                self.allow = list;
            }
            fn http_port(&self) -> u16 {
                self.http_port
            }
            fn set_http_port(&mut self, port: u16) {
                self.http_port = port;
            }
            fn update_counter(&self) -> $crate::settings::Counter {
                self.update
            }
            fn set_update_counter(&mut self, counter: $crate::settings::Counter) {
                self.update = counter;
            }
        }
    };
}

/// [`update`] for a change that cannot refuse: the store's error, if the commit failed
/// ([`StoreError::Budget`] when the administration's commit budget is spent).
pub async fn commit_change<R, A, F>(
    map: &Mutex<R, A>,
    store: &Store<F, A::Settings>,
    change: impl FnOnce(&mut A::Settings),
) -> Result<(), StoreError>
where
    R: RawMutex,
    A: SettingsAccess,
    F: NorFlash,
{
    commit_drawing(map, store, change, Draw::Admin).await
}

/// [`commit_change`] for an update's security counters: drawn from the administration's
/// budget, never refused by it ([`Draw::Counter`]).
pub async fn commit_counters<R, A, F>(
    map: &Mutex<R, A>,
    store: &Store<F, A::Settings>,
    change: impl FnOnce(&mut A::Settings),
) -> Result<(), StoreError>
where
    R: RawMutex,
    A: SettingsAccess,
    F: NorFlash,
{
    commit_drawing(map, store, change, Draw::Counter).await
}

async fn commit_drawing<R, A, F>(
    map: &Mutex<R, A>,
    store: &Store<F, A::Settings>,
    change: impl FnOnce(&mut A::Settings),
    draw: Draw,
) -> Result<(), StoreError>
where
    R: RawMutex,
    A: SettingsAccess,
    F: NorFlash,
{
    let change = |s: &mut A::Settings| {
        change(s);
        Ok::<(), core::convert::Infallible>(())
    };
    commit_within(map, store, change, draw).await.map_err(|e| match e {
        UpdateError::Store(e) => e,
        UpdateError::Refused(never) => match never {},
    })
}
