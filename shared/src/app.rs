//! The one start-up path of every module on every board: [`start`] brings up module `M` on
//! board `B` (settings, factory reset, identity, register map, network) and hands the image the
//! running module ([`App`]), whose parts the image's tasks serve (boards/image.rs). Embassy
//! tasks cannot be generic, so the image crate names the pair and declares the tasks.

use embassy_executor::{SendSpawner, SpawnError, SpawnToken, Spawner};
use embassy_sync::mutex::Mutex;
use static_cell::StaticCell;

use crate::board::{Board, IoFor, Module, Runs, Shared};
use crate::identity::{firmware_version, Identity};
use crate::module::{CommonSettings, Store};
use crate::settings::SettingsStore;

/// The running module: register map, network, identity.
pub struct App<B: Board, M: Module> {
    map: Shared<M::Map<B::Flash>>,
    store: &'static Store<B::Flash, M::Settings>,
    boot: Shared<Option<(B::Dfu, B::BootState)>>,
    net: B::Net,
    identity: Identity,
    state: &'static M::State,
}

/// The static storage of one module on one board (declare one in the image crate: Rust has
/// no generic statics).
pub struct Statics<B: Board, M: Module> {
    state: StaticCell<M::State>,
    store: StaticCell<Store<B::Flash, M::Settings>>,
    app: StaticCell<App<B, M>>,
}

impl<B: Board, M: Module> Statics<B, M> {
    /// Empty storage.
    pub const fn new() -> Self {
        Self { state: StaticCell::new(), store: StaticCell::new(), app: StaticCell::new() }
    }
}

impl<B: Board, M: Module> Default for Statics<B, M> {
    fn default() -> Self {
        Self::new()
    }
}

/// Brings module `M` up on board `B`: the board, its I/O for the module, the settings (reset
/// to factory defaults if asked), the register map and the network. Returns the running
/// module and the I/O for [`App::run`].
pub async fn start<B, M>(spawner: Spawner, statics: &'static Statics<B, M>) -> (&'static App<B, M>, B::Io)
where
    B: IoFor<M>,
    M: Module,
{
    let (mut board, flash, resources) = B::init(spawner);
    let boot = Mutex::new(board.boot_partitions());
    let reset_cause = board.reset_cause();
    crate::diagnostics::DIAGNOSTICS.start(reset_cause);
    let mut store = SettingsStore::<B::Flash, M::Settings>::open(
        flash,
        const { SettingsStore::<B::Flash, M::Settings>::config(0..B::SETTINGS_SIZE) },
    )
    .await;
    store.resume(reset_cause, board.retained());
    if board.factory_reset_requested() {
        crate::warn!("factory reset: every setting back to its factory default, the update counter kept");
        if store.commit(crate::module::factory_reset(store.get())).await.is_err() {
            crate::error!("factory reset: the settings could not be written");
        }
        if store.reset_service_records().await.is_err() {
            crate::error!("factory reset: a service's settings could not be removed");
        }
    }
    crate::info!("self-test: reset cause {:?}; settings store open", reset_cause);
    let stored = store.get().net();
    let mac = board.mac();
    let settings = *store.get();
    crate::password::AUTH.seed(&board.entropy());
    crate::diagnostics::DIAGNOSTICS.factory_password(settings.password().is_factory());
    crate::diagnostics::DIAGNOSTICS.update_key(remodaq_protocol::auth::fingerprint(&crate::identity::update_key()));
    if settings.password().is_factory() {
        crate::warn!("the factory password is in force: set one (remodaq password)");
    }
    let state: &'static M::State = statics.state.init(M::state(&settings));
    let store: &'static Store<B::Flash, M::Settings> = statics.store.init(Mutex::new(store));
    let map = Mutex::new(M::map(store, &settings, state));
    // The module's I/O starts once the settings are in force (a factory reset's sector erases
    // take longer than the STM32's capture ring lasts), just before the network.
    let io = B::io(resources);
    let (net, running) = board.start_network(spawner, stored);
    let identity = Identity { model: M::MODULE_NAME, name: M::MODEL, version: firmware_version(), mac, running };
    crate::info!("{} running, firmware {:04X}", M::MODEL, firmware_version());
    let app = statics.app.init(App { map, store, boot, net, identity, state });
    (app, io)
}

impl<B: Board, M: Module> App<B, M> {
    /// The register map, behind the lock every task takes.
    pub fn map(&'static self) -> &'static Shared<M::Map<B::Flash>> {
        &self.map
    }

    /// The settings store.
    pub fn store(&self) -> &'static Store<B::Flash, M::Settings> {
        self.store
    }

    /// The board's running network.
    pub fn net(&'static self) -> &'static B::Net {
        &self.net
    }

    /// What the module says about itself (discovery's INFO, the web console).
    pub fn identity(&self) -> Identity {
        self.identity
    }

    /// The bootloader's update and state partitions, once (to the update service); `None`
    /// afterwards, and on a board without a bootloader.
    pub async fn take_boot(&self) -> Option<(B::Dfu, B::BootState)> {
        self.boot.lock().await.take()
    }

    /// Runs the module's application over the board's I/O, forever.
    pub async fn run<Io>(&'static self, io: Io) -> !
    where
        M: Runs<Io>,
    {
        M::run(io, self.state, &self.map, B::app_alive).await
    }

    /// The live state the register map and the application share.
    pub fn state(&self) -> &'static M::State {
        self.state
    }
}

/// Which of an executor's ready tasks is polled first (embassy-executor's `scheduler-priority`:
/// at each step the ready task of the highest priority, and among equals the one woken first,
/// those the last poll woke included; docs/design.md, "Three executors"). Every task but one has
/// the same: they take turns in the order they were woken, none can keep another waiting. MQTT's
/// socket task waits while any other is ready: the service it carries runs on the background
/// executor, which waits for them all anyway.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Priority {
    /// Polled only when no other task is ready (MQTT's socket: issue #40).
    Last = 0,
    /// Every other task.
    Turn = 1,
}

/// Spawns a task, logging (instead of panicking) if its pool is exhausted.
pub fn spawn<S>(spawner: Spawner, token: Result<SpawnToken<S>, SpawnError>, name: &str) {
    spawn_at(spawner, token, name, Priority::Turn);
}

/// [`spawn`] at a [`Priority`].
pub fn spawn_at<S>(spawner: Spawner, token: Result<SpawnToken<S>, SpawnError>, name: &str, priority: Priority) {
    match token {
        Ok(token) => {
            token.metadata().set_priority(priority as u8);
            spawner.spawn(token)
        }
        Err(_) => crate::error!("cannot start task {}", name),
    }
}

/// [`spawn`] on another executor (the board's realtime one, [`Board::realtime`]).
pub fn spawn_send<S: Send>(spawner: SendSpawner, token: Result<SpawnToken<S>, SpawnError>, name: &str) {
    match token {
        Ok(token) => spawner.spawn(token),
        Err(_) => crate::error!("cannot start task {}", name),
    }
}
