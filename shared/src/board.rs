//! The board contract and the one start-up path of every module on every board.
//!
//! A board (the STM32 Nucleo, the QEMU machine, the host PC) implements [`Board`]: its settings
//! flash, its bootloader's partitions, its network and identity, the factory-reset input,
//! restart (inside its [`Network`]) and the watchdog heartbeat; and, for each module it can run, [`IoFor`]:
//! the module's I/O resources. A module (8318, 8350) implements [`Module`]: its settings
//! schema, its register map over the settings store, and ([`Runs`]) its application over the
//! board's I/O. [`start`] then brings up any module on any board the same way: settings, factory
//! reset, identity, register map, network. The image crate only names the pair and declares
//! the tasks (Embassy tasks cannot be generic), each a line calling [`App`].

use embassy_executor::{SendSpawner, SpawnError, SpawnToken, Spawner};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embedded_storage_async::nor_flash::NorFlash;
use static_cell::StaticCell;

use crate::discovery::{Effect, Identity};
use crate::identity::firmware_version;
use crate::modbus::server::{Slots, MAX_CONNECTIONS, SOCKETS};
use crate::modbus::RegisterMap;
use crate::module::{CommonSettings, SettingsAccess, Store};
use crate::net::NetConfig;
use crate::settings::{Schema, SettingsStore};
use crate::update::{UpdateService, UpdateTarget};

/// The lock every task takes to reach the register map.
pub type Shared<T> = Mutex<CriticalSectionRawMutex, T>;

/// The connection slots of the Modbus server.
pub type ModbusSlots = Slots<CriticalSectionRawMutex, SOCKETS>;

/// What every board provides.
pub trait Board: Sized + 'static {
    /// The settings flash: a NOR flash whose first [`Board::SETTINGS_SIZE`] bytes hold the
    /// settings.
    type Flash: NorFlash + 'static;
    /// Size of the settings region, bytes.
    const SETTINGS_SIZE: u32;
    /// Modbus connections one source address may hold (docs/modbus.md): 4, unless every
    /// client reaches the board through one address (QEMU's user network).
    const CONNECTIONS_PER_SOURCE: usize = crate::modbus::server::PER_SOURCE;
    /// The running network (Modbus/TCP, discovery, firmware updates).
    type Net: Network;
    /// The bootloader's update (DFU) partition (firmware updates, docs/update.md).
    type Dfu: NorFlash + 'static;
    /// The bootloader's state partition.
    type BootState: NorFlash + 'static;
    /// What the board reserves for the modules' I/O (pins and peripherals; the scenario on the
    /// host), handed to [`IoFor::io`].
    type Resources;

    /// Brings up the board (clocks, pins, peripherals; on the host: command line, logging):
    /// the board, its settings flash and the modules' I/O resources.
    /// The watchdog, where the board has one, starts here (tasks may be spawned).
    fn init(spawner: Spawner) -> (Self, Self::Flash, Self::Resources);
    /// The bootloader's update and state partitions; `None` on a board without a bootloader
    /// (the host), which then serves no firmware updates.
    fn boot_partitions(&mut self) -> Option<(Self::Dfu, Self::BootState)>;
    /// Why this run started (diagnostics register 00F3h).
    fn reset_cause(&self) -> crate::diagnostics::ResetCause;
    /// Every setting must return to its factory default (the USER button held at power-up,
    /// `--factory-reset` on the host).
    fn factory_reset_requested(&self) -> bool;
    /// The module's MAC address.
    fn mac(&self) -> [u8; 6];
    /// 32 bytes from the board's entropy source, to seed the module's random numbers (nonces
    /// and key-agreement keys, docs/security.md): the STM32's RNG, the host's OS.
    fn entropy(&mut self) -> [u8; 32];
    /// Starts the network with the stored settings, and the board's own tasks (network
    /// runner, watchdog, identify LED). Returns the network and the settings actually in force
    /// (the host and QEMU boards listen where they are told, not at the stored address).
    fn start_network(self, spawner: Spawner, stored: NetConfig) -> (Self::Net, NetConfig);
    /// The application completed a cycle (feeds the watchdog where the board has one).
    fn app_alive();
    /// The board's realtime executor, for a module's time-critical I/O loop ([`RunsRealtime`]):
    /// it preempts every task of the main executor (`spawner`'s), so a long computation there
    /// (an update's ed25519 check, a login's key agreement: several milliseconds on the
    /// Cortex-M4) cannot delay it. An interrupt-driven executor on the STM32 and QEMU boards;
    /// on the host, whose tasks run on threads of a PC, `spawner`'s own. Called once, at start.
    fn realtime(spawner: Spawner) -> SendSpawner;
}

/// A board's network: serves one Modbus/TCP connection slot, and the discovery protocol with
/// the board's identify and restart.
#[allow(async_fn_in_trait)]
pub trait Network: 'static {
    /// Accepts and serves Modbus/TCP connections in `slot`, forever.
    async fn serve_modbus<M: RegisterMap>(
        &'static self,
        map: &'static Shared<M>,
        slots: &'static ModbusSlots,
        slot: usize,
    ) -> !;
    /// Serves the discovery and configuration protocol, forever.
    async fn serve_discovery<A: SettingsAccess, F: NorFlash>(
        &'static self,
        map: &'static Shared<A>,
        store: &'static Store<F, A::Settings>,
        identity: Identity,
    ) -> !;
    /// Serves firmware update sessions (TCP port 8301) into `target`, one at a time, forever;
    /// restarts the module after an image was verified and marked.
    async fn serve_update<A: SettingsAccess, F: NorFlash, U: UpdateTarget>(
        &'static self,
        map: &'static Shared<A>,
        store: &'static Store<F, A::Settings>,
        service: &mut UpdateService,
        target: &mut U,
    ) -> !;
    /// Serves the web console's connections, one at a time per task (docs/web.md), forever.
    /// So far only the host board has the console (`--http`); the others wait for ever.
    async fn serve_web<A: RegisterMap + SettingsAccess, F: NorFlash>(
        &'static self,
        map: &'static Shared<A>,
        store: &'static Store<F, A::Settings>,
        identity: Identity,
    ) -> ! {
        let _ = (map, store, identity);
        core::future::pending().await
    }
    /// Whether the network is up (the link, and an address), for the self-test.
    fn is_up(&self) -> bool;
    /// Restarts the module (as discovery's restart command does).
    async fn restart(&self) -> !;
}

/// How a board carries out what the discovery service asks, after the reply was sent: blink
/// the identify LED, restart (new network settings take effect). Each board's [`Network`]
/// serves discovery with its own.
#[allow(async_fn_in_trait)]
pub trait Effects: 'static {
    /// Carries out `effect`.
    async fn apply(&self, effect: Effect);
}

/// What a module is, whatever board it runs on.
pub trait Module: Sized + 'static {
    /// Module name register value (40211).
    const MODULE_NAME: u16;
    /// Model string.
    const MODEL: &'static str;
    /// The settings schema.
    type Settings: CommonSettings;
    /// Live state shared by the register map and the application outside the map's lock
    /// (the 8350's engines); `()` where there is none.
    type State: 'static;
    /// The register map over the settings store.
    type Map<F: NorFlash + 'static>: RegisterMap + SettingsAccess<Settings = Self::Settings> + 'static;

    /// The live state, configured from the settings.
    fn state(settings: &Self::Settings) -> Self::State;
    /// The register map over the opened store (`settings`: the settings in force).
    fn map<F: NorFlash + 'static>(
        store: &'static Store<F, Self::Settings>,
        settings: &Self::Settings,
        state: &'static Self::State,
    ) -> Self::Map<F>;
}

/// A module's application over the I/O resources `Io` of a board.
#[allow(async_fn_in_trait)]
pub trait Runs<Io>: Module {
    /// Runs the module's I/O forever; `alive` after each completed cycle.
    async fn run<F: NorFlash + 'static>(
        io: Io,
        state: &'static Self::State,
        map: &'static Shared<Self::Map<F>>,
        alive: impl FnMut(),
    ) -> !;
}

/// A module's time-critical I/O loop over the I/O resources `Io` of a board: it needs only the
/// live state (no register map, no lock a thread-mode task may hold), so it runs on the board's
/// realtime executor ([`Board::realtime`]). The 8350's: its output pattern is refilled every
/// 6.4 ms and its input capture drained every 2 ms.
#[allow(async_fn_in_trait)]
pub trait RunsRealtime<Io>: Module {
    /// Runs the module's I/O forever; `alive` after each completed cycle.
    async fn run_realtime(io: Io, state: &'static Self::State, alive: fn()) -> !;
}

/// The I/O a board gives module `M` (a board implements it for each module it can run).
pub trait IoFor<M: Module>: Board {
    /// The module's I/O, ready to use.
    type Io;
    /// Starts the module's I/O from the board's resources (after the settings are loaded,
    /// before the network starts).
    fn io(resources: Self::Resources) -> Self::Io;
}

/// The running module: register map, network, identity.
pub struct App<B: Board, M: Module> {
    map: Shared<M::Map<B::Flash>>,
    store: &'static Store<B::Flash, M::Settings>,
    boot: Shared<Option<(B::Dfu, B::BootState)>>,
    net: B::Net,
    slots: ModbusSlots,
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
    if board.factory_reset_requested() {
        crate::warn!("factory reset: every setting back to its factory default");
        if store.commit(M::Settings::defaults()).await.is_err() {
            crate::error!("factory reset: the settings could not be written");
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
    let app = statics.app.init(App {
        map,
        store,
        boot,
        net,
        slots: Slots::new(MAX_CONNECTIONS, B::CONNECTIONS_PER_SOURCE),
        identity,
        state,
    });
    (app, io)
}

impl<B: Board, M: Module> App<B, M> {
    /// Serves Modbus/TCP connection slot `slot` (0..[`SOCKETS`]), forever.
    pub async fn serve_modbus(&'static self, slot: usize) -> ! {
        self.net.serve_modbus(&self.map, &self.slots, slot).await
    }

    /// Serves web console connections, forever (a board without the console waits for ever).
    pub async fn serve_web(&'static self) -> ! {
        self.net.serve_web(&self.map, self.store, self.identity).await
    }

    /// Serves discovery, forever.
    pub async fn serve_discovery(&'static self) -> ! {
        self.net.serve_discovery(&self.map, self.store, self.identity).await
    }

    /// Confirms a new image after its self-test, then serves firmware updates, forever (on a
    /// board without a bootloader: waits forever).
    pub async fn serve_update(&'static self) -> ! {
        let parts = self.boot.lock().await.take();
        match parts {
            Some((dfu, state)) => {
                crate::update::run(&self.net, &self.map, self.store, M::MODULE_NAME, self.identity.mac, dfu, state)
                    .await
            }
            None => core::future::pending().await,
        }
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

    /// Spawns the module's tasks: `modbus` once per connection slot, `discovery`, `update`,
    /// then `app` with the I/O (which spawns the module's application where it runs: the
    /// main executor, or the board's realtime one). A task that cannot be spawned is logged,
    /// not a panic.
    pub fn spawn<Io, S1, S2, S4>(
        &'static self,
        spawner: Spawner,
        io: Io,
        modbus: impl Fn(&'static Self, usize) -> Result<SpawnToken<S1>, SpawnError>,
        discovery: impl FnOnce(&'static Self) -> Result<SpawnToken<S2>, SpawnError>,
        update: impl FnOnce(&'static Self) -> Result<SpawnToken<S4>, SpawnError>,
        app: impl FnOnce(Spawner, &'static Self, Io),
    ) {
        for slot in 0..SOCKETS {
            spawn(spawner, modbus(self, slot), "modbus");
        }
        spawn(spawner, discovery(self), "discovery");
        spawn(spawner, update(self), "update");
        app(spawner, self, io);
    }
}

/// Spawns a task, logging (instead of panicking) if its pool is exhausted.
pub fn spawn<S>(spawner: Spawner, token: Result<SpawnToken<S>, SpawnError>, name: &str) {
    match token {
        Ok(token) => spawner.spawn(token),
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
