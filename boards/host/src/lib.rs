//! The host board: everything a simulated module needs from the PC. Std TCP sockets for the
//! Modbus server, a flash image file for the settings, the command line and logging. Only
//! this crate (and the STM32 / QEMU boards beside it) knows about hardware or the OS.

pub mod cli;
pub mod discovery;
pub mod flash;
pub mod modbus;
pub mod scenario;
pub mod testing;

/// Logging to stderr through `log`; `RUST_LOG` overrides the default level (info).
pub fn init_logging() {
    let _ = env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("info")).try_init();
}

use std::path::PathBuf;

use clap::Parser;
use remodaq_shared::identity::FIRMWARE_VERSION;
use remodaq_shared::module::CommonSettings;
use remodaq_shared::net::{mac_from_uid, NetConfig};
use remodaq_shared::settings::{Schema, SettingsStore};

/// A started simulated module: its options, settings and listener.
pub struct Started<S: Schema> {
    /// The command line.
    pub options: cli::Options,
    /// The settings store over the flash image.
    pub store: SettingsStore<flash::FileFlash, S>,
    /// The Modbus/TCP listener.
    pub listener: &'static modbus::Listener,
    /// The discovery socket.
    pub discovery: discovery::HostDatagrams,
    /// What discovery tells about the module.
    pub identity: remodaq_shared::discovery::Identity,
}

/// Common start-up: logging, command line, flash image, settings, listener and discovery
/// socket. Exits the process with a clear message (and status 2) when the flash image or an
/// address cannot be used. `model` is the module name register value (8318h, 8350h).
pub async fn start<S: CommonSettings>(model: u16) -> Started<S> {
    let name = format!("{model:04X}");
    init_logging();
    let options = cli::Options::parse();
    let path: PathBuf = options.flash_path(&name);
    let flash = flash::FileFlash::open(&path).unwrap_or_else(|e| fail(&format!("flash image {}: {e}", path.display())));
    let mut store =
        SettingsStore::open(flash, const { SettingsStore::<flash::FileFlash, S>::config(0..flash::SIZE as u32) }).await;
    if options.factory_reset {
        log::warn!("factory reset: every setting back to its factory default");
        if store.commit(S::defaults()).await.is_err() {
            fail("factory reset: the settings could not be written");
        }
    }
    let net = store.get().net();
    let addr = options.listen_addr(net.port);
    let listener = modbus::bind(addr).unwrap_or_else(|e| fail(&format!("cannot listen on {addr}: {e}")));
    let local = listener.get_ref().local_addr().unwrap_or(addr);
    log::info!("RemoDAQ-{name} simulated module: settings in {}", path.display());
    log::info!("modbus: listening on {local}");
    let discovery = discovery::HostDatagrams::bind(options.discovery)
        .unwrap_or_else(|e| fail(&format!("cannot listen on {}: {e}", options.discovery)));
    // The simulated module's MAC: stable for its flash image, like the MCU's unique id.
    let canonical = std::fs::canonicalize(&path).unwrap_or(path.clone());
    let digest = <sha2::Sha256 as sha2::Digest>::digest(canonical.to_string_lossy().as_bytes());
    let mut uid = [0u8; 12];
    uid.copy_from_slice(&digest[..12]);
    let running = match local.ip() {
        std::net::IpAddr::V4(ip) if !ip.is_unspecified() => NetConfig { ip: ip.octets(), port: local.port(), ..net },
        _ => NetConfig { port: local.port(), ..net },
    };
    let identity = remodaq_shared::discovery::Identity {
        model,
        name: if model == 0x8318 { "RemoDAQ-8318" } else { "RemoDAQ-8350" },
        version: FIRMWARE_VERSION,
        mac: mac_from_uid(&uid),
        running,
    };
    Started { options, store, listener: Box::leak(Box::new(listener)), discovery, identity }
}

/// Exits the process with a clear message and status 2 (start-up errors).
pub fn fail(message: &str) -> ! {
    eprintln!("error: {message}");
    std::process::exit(2)
}

/// Declares a simulated module's network tasks for the register map type `$map` (behind a
/// `Mutex<CriticalSectionRawMutex, _>`): `modbus_task` (one per connection slot),
/// `discovery_task`, and `spawn_network(spawner, started, map)` that starts them.
/// (Embassy tasks cannot be generic, so each firmware declares concrete ones.)
#[macro_export]
macro_rules! host_network_tasks {
    ($map:ty) => {
        static SLOTS: $crate::modbus::ModbusSlots =
            remodaq_shared::modbus::server::Slots::new(remodaq_shared::modbus::server::MAX_CONNECTIONS);

        #[embassy_executor::task(pool_size = remodaq_shared::modbus::server::SOCKETS)]
        async fn modbus_task(listener: &'static $crate::modbus::Listener, map: &'static $map, slot: usize) -> ! {
            $crate::modbus::connection_task(listener, map, &SLOTS, slot).await
        }

        #[embassy_executor::task]
        async fn discovery_task(
            socket: $crate::discovery::HostDatagrams,
            map: &'static $map,
            identity: remodaq_shared::discovery::Identity,
        ) -> ! {
            $crate::discovery::run(socket, map, identity).await
        }

        /// Starts the Modbus/TCP connection tasks and the discovery service.
        fn spawn_network(
            spawner: &embassy_executor::Spawner,
            listener: &'static $crate::modbus::Listener,
            discovery: $crate::discovery::HostDatagrams,
            identity: remodaq_shared::discovery::Identity,
            map: &'static $map,
        ) {
            for slot in 0..remodaq_shared::modbus::server::SOCKETS {
                match modbus_task(listener, map, slot) {
                    Ok(token) => spawner.spawn(token),
                    Err(e) => log::error!("cannot start Modbus task {slot}: {e:?}"),
                }
            }
            match discovery_task(discovery, map, identity) {
                Ok(token) => spawner.spawn(token),
                Err(e) => log::error!("cannot start the discovery task: {e:?}"),
            }
        }
    };
}
