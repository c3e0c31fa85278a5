//! The board contract: what every board provides, and what every module is.
//!
//! A board (the STM32 Nucleo, the QEMU machine, the host PC) implements [`Board`]: its settings
//! flash, its bootloader's partitions, its network and identity, the factory-reset input,
//! restart (inside its [`Network`]) and the watchdog heartbeat; and, for each module it can run,
//! [`IoFor`]: the module's I/O resources. A module (8318, 8350) implements [`Module`]: its
//! settings schema, its register map over the settings store, and ([`Runs`]) its application
//! over the board's I/O. The contract knows no network service: `crate::app::start` brings up
//! any module on any board the same way, and the image (boards/image.rs) runs the services.

use embassy_executor::{SendSpawner, Spawner};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embedded_storage_async::nor_flash::NorFlash;

use crate::modbus::RegisterMap;
use crate::module::{CommonSettings, SettingsAccess, Store};
use crate::net::NetConfig;

/// The lock every task takes to reach the register map.
pub type Shared<T> = Mutex<CriticalSectionRawMutex, T>;

/// What every board provides.
pub trait Board: Sized + 'static {
    /// The settings flash: a NOR flash whose first [`Board::SETTINGS_SIZE`] bytes hold the
    /// settings.
    type Flash: NorFlash + 'static;
    /// Size of the settings region, bytes.
    const SETTINGS_SIZE: u32;
    /// Modbus connections one source address may hold (docs/modbus.md): 4, unless every
    /// client reaches the board through one address (QEMU's user network).
    const CONNECTIONS_PER_SOURCE: usize = crate::sockets::MODBUS_PER_SOURCE;
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
    /// What the last restart left for this start ([`crate::settings::Retained`]: the flash
    /// commit budgets' debts), read once: the board keeps the words a restart writes where a
    /// reset does not clear them, and clears them here.
    fn retained(&mut self) -> Option<crate::settings::Retained>;
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

/// A board's running network, as the module runtime sees it: whether it is up, and the
/// module's restart. The network services (Modbus/TCP, discovery, updates, the web console) are
/// not part of the contract: each is a crate of its own under `services/`, run over the board's
/// network by the image (boards/image.rs).
#[allow(async_fn_in_trait)]
pub trait Network: 'static {
    /// Whether the network is up (the link, and an address), for the self-test.
    fn is_up(&self) -> bool;
    /// Restarts the module (as discovery's restart command does).
    async fn restart(&self) -> !;
}

/// What the board must do after sending the reply.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Effect {
    /// Nothing.
    None,
    /// Restart the module (new network settings take effect).
    Restart,
    /// Blink the identify LED for 10 s.
    Identify,
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
/// live state (no register map, no lock a main-executor task may hold), so it runs on the board's
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
