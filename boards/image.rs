// The firmware image of one module on one board: included by `firmware-8318/src/main.rs` and
// `firmware-8350/src/main.rs` after each names its `Module`. The board is chosen at build time:
// the host board on a PC; on `thumbv7em-none-eabihf` the STM32 board (default feature
// `board-stm32`) or the QEMU board (`--no-default-features --features board-qemu`). Everything
// else is the one start-up path of `remodaq_shared::board`. Embassy tasks cannot be generic, so
// the three below are declared here, each a line calling the running module; the module's
// application task is declared by the image crate (`application`, spawned by its
// `spawn_application`), on the main executor (the 8318) or the board's realtime one (the 8350).

#[cfg(all(target_os = "none", feature = "board-stm32", feature = "board-qemu"))]
compile_error!("choose one board: `board-stm32` (default) or `--no-default-features --features board-qemu`");

// An STM32 image (a module's) never trusts the repository's test update key (its secret half is
// public) unless this image crate was asked for it: Cargo unifies features, so the test key
// that another crate of the same build asked for (the QEMU board, the on-target tests) would
// otherwise reach this image silently. Nothing depends on an image crate, so its own feature
// is never switched on by another (docs/security.md).
#[cfg(all(target_os = "none", not(feature = "board-qemu")))]
const _: () = assert!(
    cfg!(feature = "test-update-key") || !build::UPDATE_KEY_IS_TEST_KEY,
    "this STM32 image would trust the repository's TEST update key: build it with REMODAQ_UPDATE_KEY, \
     or ask for the test key explicitly (feature test-update-key, test builds only)"
);

/// What this image's build fixed (boards/update-key.rs, run by this crate's build script): the
/// update key and the firmware version, read here so that another key or version rebuilds only
/// the image crate.
mod build {
    include!(concat!(env!("OUT_DIR"), "/update_key.rs"));
    include!(concat!(env!("OUT_DIR"), "/firmware_version.rs"));

    /// The build's identity, for the runtime.
    pub const BUILD: remodaq_shared::identity::Build = remodaq_shared::identity::Build {
        version: match FIRMWARE_VERSION_OVERRIDE {
            Some(version) => version,
            None => remodaq_shared::identity::FIRMWARE_VERSION,
        },
        update_key: UPDATE_KEY,
    };

    /// The security counter this image is built with (protocol's `SECURITY_COUNTER`, or
    /// `REMODAQ_SECURITY_COUNTER` for a test image).
    #[allow(dead_code)]
    pub const SECURITY_COUNTER: u32 = match SECURITY_COUNTER_OVERRIDE {
        Some(counter) => counter,
        None => remodaq_shared::identity::SECURITY_COUNTER,
    };
}

/// This image's identity (its model and security counter), where the bootloaders read it before
/// a swap: `IDENTITY_AT` bytes into the image, where both boards' memory.x place this section
/// (docs/update.md, "Anti-rollback"; security review finding 11c). `remodaq sign` reads it too.
#[cfg(target_os = "none")]
#[link_section = ".remodaq_identity"]
#[used]
static IDENTITY: [u8; remodaq_shared::protocol::update::IDENTITY_LEN] = remodaq_shared::protocol::update::Identity {
    model: <Module as remodaq_shared::board::Module>::MODULE_NAME,
    counter: build::SECURITY_COUNTER,
}
.encode();

#[cfg(not(target_os = "none"))]
use remodaq_board_host::HostBoard as Board;
#[cfg(all(target_os = "none", feature = "board-qemu"))]
use remodaq_board_qemu::QemuBoard as Board;
#[cfg(all(target_os = "none", not(feature = "board-qemu")))]
use remodaq_board_stm32::Stm32Board as Board;

use embassy_executor::Spawner;
use remodaq_shared::app::{App, Statics};
use remodaq_shared::board::IoFor;

/// The module on this board, running.
type Running = App<Board, Module>;
/// The board's I/O for the module.
type Io = <Board as IoFor<Module>>::Io;

static STATICS: Statics<Board, Module> = Statics::new();

/// The network services' transports on this board: each service's own on embassy-net (the STM32
/// and QEMU boards), the host board's over std sockets. Each is `serve(net, ...)` for the board's
/// running network.
#[cfg(target_os = "none")]
mod transport {
    pub use remodaq_discovery::embassy::serve as discovery;
    pub use remodaq_modbus::embassy::serve as modbus;
    pub use remodaq_update::embassy::serve as update;
    #[cfg(feature = "web")]
    pub use remodaq_web::embassy::serve as web;
}
#[cfg(not(target_os = "none"))]
use remodaq_board_host::services as transport;

/// The Modbus server's connection slots (spec §1.1: eviction of the connection idle longest).
static SLOTS: remodaq_modbus::ModbusSlots = remodaq_modbus::ModbusSlots::new(
    remodaq_modbus::server::MAX_CONNECTIONS,
    <Board as remodaq_shared::board::Board>::CONNECTIONS_PER_SOURCE,
);

/// A Modbus/TCP connection slot (0..SOCKETS): accepts and serves connections, forever.
#[embassy_executor::task(pool_size = remodaq_modbus::server::SOCKETS)]
async fn modbus(app: &'static Running, slot: usize) -> ! {
    transport::modbus(app.net(), app.map(), &SLOTS, slot).await
}

/// The discovery and configuration service, forever.
#[embassy_executor::task]
async fn discovery(app: &'static Running) -> ! {
    transport::discovery(app.net(), app.map(), app.store(), app.identity()).await
}

/// Confirms a new image after its self-test, then serves firmware updates, forever (a board
/// without a bootloader: waits for ever). The host board has no bootloader and no such task.
#[cfg(target_os = "none")]
#[embassy_executor::task]
async fn update(app: &'static Running) -> ! {
    match app.take_boot().await {
        Some((dfu, state)) => {
            let mac = app.identity().mac;
            transport::update(app.net(), app.map(), app.store(), <Module as remodaq_shared::board::Module>::MODULE_NAME, mac, dfu, state).await
        }
        None => core::future::pending().await,
    }
}

/// The web console (docs/web.md): on the host board (`--http`) and in an image built with the
/// feature `web` (the QEMU board's).
#[cfg(any(not(target_os = "none"), feature = "web"))]
#[embassy_executor::task(pool_size = remodaq_shared::sockets::WEB_CONNECTIONS)]
async fn web(app: &'static Running) -> ! {
    // Made in place: awaited by value, its 3.6 KB (the connection's buffers) would be copied
    // through the stack first (issue #39, the stack).
    core::pin::pin!(transport::web(app.net(), app.map(), app.store(), app.identity())).await
}

/// MQTT (docs/mqtt.md), with the stored settings, on the host board (or `--mqtt`'s).
#[cfg(not(target_os = "none"))]
#[embassy_executor::task]
async fn mqtt(app: &'static Running) -> ! {
    // Made in place, as the web console's (its buffers would be copied through the stack).
    core::pin::pin!(transport::mqtt(app.net(), app.map(), app.store(), app.identity())).await
}

/// MQTT on the target boards (in an image built with the feature `mqtt`: every one by default),
/// in two tasks (docs/mqtt.md, "Never in the way"): the service on the background executor,
/// which every other task preempts ([`mqtt`], given these parts of the running module once the
/// start-up made it), and its socket on the main one ([`mqtt_link`]).
#[cfg(all(target_os = "none", feature = "mqtt"))]
mod mqtt_parts {
    use super::{Board, Module};
    use remodaq_shared::board::Shared;
    use remodaq_shared::module::Store;

    type Flash = <Board as remodaq_shared::board::Board>::Flash;
    /// The register map, the settings' store and the identity.
    pub type Parts = (
        &'static Shared<<Module as remodaq_shared::board::Module>::Map<Flash>>,
        &'static Store<Flash, <Module as remodaq_shared::board::Module>::Settings>,
        remodaq_shared::identity::Identity,
    );
    pub static PARTS: embassy_sync::signal::Signal<embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex, Parts> =
        embassy_sync::signal::Signal::new();
}

/// MQTT's service, on the background executor (see [`mqtt_parts`]).
#[cfg(all(target_os = "none", feature = "mqtt"))]
#[embassy_executor::task]
async fn mqtt() -> ! {
    let (map, store, identity) = mqtt_parts::PARTS.wait().await;
    // Made in place: it holds TLS's record buffers.
    core::pin::pin!(remodaq_mqtt::embassy::serve(map, store, identity)).await
}

/// MQTT's socket and the SNTP client, on the main executor (see [`mqtt_parts`]).
#[cfg(all(target_os = "none", feature = "mqtt"))]
#[embassy_executor::task]
async fn mqtt_link(app: &'static Running) -> ! {
    core::pin::pin!(remodaq_mqtt::embassy::link(app.net())).await
}

/// Brings the module up, then starts its tasks: a Modbus connection task per slot, discovery,
/// MQTT (where built), updates (target boards), the module's application (main or realtime
/// executor, by the image crate), and the web console's connection tasks. A task that cannot be spawned is logged, not
/// a panic.
async fn start(spawner: Spawner) {
    use remodaq_shared::app::spawn;
    remodaq_shared::identity::set_build(build::BUILD);
    let (app, io) = remodaq_shared::app::start(spawner, &STATICS).await;
    for slot in 0..remodaq_modbus::server::SOCKETS {
        spawn(spawner, modbus(app, slot), "modbus");
    }
    spawn(spawner, discovery(app), "discovery");
    #[cfg(not(target_os = "none"))]
    spawn(spawner, mqtt(app), "mqtt");
    #[cfg(all(target_os = "none", feature = "mqtt"))]
    {
        use remodaq_shared::app::{spawn_at, Priority};
        spawn_at(spawner, mqtt_link(app), "mqtt", Priority::Last);
        mqtt_parts::PARTS.signal((app.map(), app.store(), app.identity()));
    }
    #[cfg(target_os = "none")]
    spawn(spawner, update(app), "update");
    spawn_application(spawner, app, io);
    #[cfg(any(not(target_os = "none"), feature = "web"))]
    for _ in 0..remodaq_shared::sockets::WEB_CONNECTIONS {
        spawn(spawner, web(app), "web");
    }
}

#[cfg(not(target_os = "none"))]
#[embassy_executor::main]
async fn main(spawner: Spawner) {
    start(spawner).await;
}

/// The target boards run their own executors (`remodaq_board_qemu::executor`,
/// `remodaq_board_stm32::executor`): the main one polled from an interrupt, the background one
/// in thread mode, below it (the services' long computations, MQTT's service).
#[cfg(target_os = "none")]
#[cortex_m_rt::entry]
fn main() -> ! {
    #[cfg(feature = "board-qemu")]
    use {remodaq_board_qemu::executor::run, remodaq_shared::app::spawn as spawn_main};
    #[cfg(not(feature = "board-qemu"))]
    use {remodaq_board_stm32::executor::run, remodaq_shared::app::spawn_send as spawn_main};
    run(|background, main| {
        spawn_main(main, main_task(), "main");
        remodaq_shared::app::spawn(background, offload_worker(), "offload");
        #[cfg(feature = "mqtt")]
        remodaq_shared::app::spawn(background, mqtt(), "mqtt");
    })
}

/// The start-up, then the tasks' spawning, on the main executor.
#[cfg(target_os = "none")]
#[embassy_executor::task]
async fn main_task() {
    // The main executor's `Spawner` (an interrupt executor gives a `SendSpawner` only, whose
    // tasks' arguments must be `Send`; embassy-executor 0.10 names this the case that needs it).
    // SAFETY: awaited in a task of an embassy executor, with the context it polls it with.
    let spawner = unsafe { Spawner::for_current_executor() }.await;
    start(spawner).await;
}

/// The services' long computations (`remodaq_shared::offload`: key agreements, an update's
/// signature check), on the board's background executor, which every other task preempts.
#[cfg(target_os = "none")]
#[embassy_executor::task]
async fn offload_worker() -> ! {
    remodaq_shared::offload::work().await
}
