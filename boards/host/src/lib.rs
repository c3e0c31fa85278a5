//! The host board: a RemoDAQ module simulated on a PC (Linux, macOS, Windows). Std sockets for
//! Modbus/TCP and discovery, a flash image file for the settings, the command line, logging,
//! and the modules' terminals from a scenario file. It implements the board contract
//! (`remodaq_shared::board`) like the STM32 and QEMU boards; only this crate knows about the OS.

pub mod analog;
pub mod cli;
pub mod digital;
pub mod discovery;
pub mod flash;
pub mod modbus;
pub mod mqtt;
pub mod scenario;
pub mod services;
pub mod testing;
pub mod web;

use std::net::SocketAddr;
use std::path::PathBuf;

use clap::Parser;
use embassy_executor::{SendSpawner, Spawner};
use remodaq_shared::board::{Board, Effects, Network};
use remodaq_shared::net::{mac_from_uid, NetConfig};

/// Logging to stderr through `log`; `RUST_LOG` overrides the default level (info).
pub fn init_logging() {
    let _ = env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("info")).try_init();
}

/// Exits the process with a clear message and status 2 (start-up errors).
pub fn fail(message: &str) -> ! {
    eprintln!("error: {message}");
    std::process::exit(2)
}

/// Binds with `bind`, trying again for up to 5 s while the address is in use: after a restart
/// (spawn-and-exit on Windows) the old process may not have let go of it yet.
fn retry<T>(mut bind: impl FnMut() -> std::io::Result<T>) -> std::io::Result<T> {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
    loop {
        match bind() {
            Err(e) if e.kind() == std::io::ErrorKind::AddrInUse && std::time::Instant::now() < deadline => {
                std::thread::sleep(std::time::Duration::from_millis(100));
            }
            result => return result,
        }
    }
}

/// The PC as a board.
pub struct HostBoard {
    options: cli::Options,
    path: PathBuf,
}

/// The host board's I/O resources: the scenario file, if one was given.
pub struct Scenario(pub Option<PathBuf>);

/// The simulated module's network: the Modbus/TCP listener and the discovery socket.
pub struct HostNet {
    /// The Modbus/TCP listener.
    pub(crate) listener: modbus::Listener,
    /// The discovery socket.
    pub(crate) discovery: discovery::HostDatagrams,
    /// The web console's listener (`--http`).
    pub(crate) web: Option<web::Listener>,
    /// The MQTT broker (`--mqtt`).
    pub(crate) mqtt: Option<SocketAddr>,
}

impl Board for HostBoard {
    type Flash = flash::FileFlash;
    const SETTINGS_SIZE: u32 = flash::SIZE as u32;
    type Net = HostNet;
    /// No bootloader on a PC (placeholders: `boot_partitions` gives none).
    type Dfu = remodaq_shared::ram_flash::RamFlash<4, 4>;
    type BootState = remodaq_shared::ram_flash::RamFlash<4, 4>;
    type Resources = Scenario;

    /// Logging, the command line and the flash image; a flash image that cannot be used ends
    /// the process with status 2.
    fn init(_spawner: Spawner) -> (Self, flash::FileFlash, Scenario) {
        init_logging();
        let options = cli::Options::parse();
        let path = options.flash_path();
        let mut flash =
            flash::FileFlash::open(&path).unwrap_or_else(|e| fail(&format!("flash image {}: {e}", path.display())));
        log::info!("settings in {}", path.display());
        if options.slow_flash > 0 {
            log::info!("slow flash: every write and erase takes {} ms longer", options.slow_flash);
            flash.slow_down(std::time::Duration::from_millis(options.slow_flash));
        }
        let scenario = Scenario(options.scenario.clone());
        (Self { options, path }, flash, scenario)
    }

    fn factory_reset_requested(&self) -> bool {
        self.options.factory_reset
    }

    /// `--mac`, else stable for a flash image, as the MCU's unique id is for a module.
    fn mac(&self) -> [u8; 6] {
        if let Some(mac) = self.options.mac {
            return mac;
        }
        let canonical = std::fs::canonicalize(&self.path).unwrap_or(self.path.clone());
        let digest = <sha2::Sha256 as sha2::Digest>::digest(canonical.to_string_lossy().as_bytes());
        let mut uid = [0u8; 12];
        uid.copy_from_slice(&digest[..12]);
        mac_from_uid(&uid)
    }

    /// From the OS (getrandom).
    fn entropy(&mut self) -> [u8; 32] {
        let mut seed = [0u8; 32];
        if let Err(e) = getrandom::fill(&mut seed) {
            fail(&format!("no random numbers from the OS: {e}"));
        }
        seed
    }

    /// Binds the listener (`--listen`, the stored port by default) and the discovery socket;
    /// an address that cannot be used ends the process with status 2. The settings in force
    /// are the stored ones with the address actually listened on.
    fn start_network(self, _spawner: Spawner, stored: NetConfig) -> (HostNet, NetConfig) {
        let addr = self.options.listen_addr(stored.port);
        let listener = retry(|| modbus::bind(addr)).unwrap_or_else(|e| fail(&format!("cannot listen on {addr}: {e}")));
        let local: SocketAddr = listener.get_ref().local_addr().unwrap_or(addr);
        log::info!("modbus: listening on {local}");
        let discovery = retry(|| discovery::HostDatagrams::bind(self.options.discovery))
            .unwrap_or_else(|e| fail(&format!("cannot listen on {}: {e}", self.options.discovery)));
        let running = match local.ip() {
            std::net::IpAddr::V4(ip) if !ip.is_unspecified() => {
                NetConfig { ip: ip.octets(), port: local.port(), ..stored }
            }
            _ => NetConfig { port: local.port(), ..stored },
        };
        let web = self.options.http.map(|addr| {
            let web = retry(|| web::bind(addr)).unwrap_or_else(|e| fail(&format!("cannot listen on {addr}: {e}")));
            log::info!("web: listening on {}", web.get_ref().local_addr().unwrap_or(addr));
            web
        });
        (HostNet { listener, discovery, web, mqtt: self.options.mqtt }, running)
    }

    /// The PC has no watchdog.
    fn app_alive() {}

    /// The main executor's own: the simulator's tasks run on a PC's threads, not one core.
    fn realtime(spawner: Spawner) -> SendSpawner {
        spawner.make_send()
    }

    /// Power-on, or a software restart when this process was started by a restart.
    fn boot_partitions(&mut self) -> Option<(Self::Dfu, Self::BootState)> {
        None
    }

    fn reset_cause(&self) -> remodaq_shared::diagnostics::ResetCause {
        if std::env::var_os(discovery::RESTARTED).is_some() {
            remodaq_shared::diagnostics::ResetCause::Software
        } else {
            remodaq_shared::diagnostics::ResetCause::PowerOn
        }
    }

    /// The words the restart put in this process's environment ([`discovery::RETAINED`]).
    fn retained(&mut self) -> Option<remodaq_shared::settings::Retained> {
        let text = std::env::var(discovery::RETAINED).ok()?;
        let mut words = [0u32; 4];
        let mut parts = text.split(',');
        for word in &mut words {
            *word = parts.next()?.parse().ok()?;
        }
        remodaq_shared::settings::Retained::from_words(words)
    }
}

impl Network for HostNet {
    fn is_up(&self) -> bool {
        true
    }

    async fn restart(&self) -> ! {
        discovery::HostEffects.apply(remodaq_shared::board::Effect::Restart).await;
        fail("restart failed")
    }
}
