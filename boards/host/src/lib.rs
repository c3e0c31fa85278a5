//! The host board: everything a simulated module needs from the PC. Std TCP sockets for the
//! Modbus server, a flash image file for the settings, the command line and logging. Only
//! this crate (and the STM32 / QEMU boards beside it) knows about hardware or the OS.

pub mod cli;
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
use remodaq_shared::settings::{Schema, SettingsStore};

/// A started simulated module: its options, settings and listener.
pub struct Started<S: Schema> {
    /// The command line.
    pub options: cli::Options,
    /// The settings store over the flash image.
    pub store: SettingsStore<flash::FileFlash, S>,
    /// The Modbus/TCP listener.
    pub listener: &'static modbus::Listener,
}

/// Common start-up: logging, command line, flash image, settings, listener. Exits the process
/// with a clear message (and status 2) when the flash image or the address cannot be used.
pub async fn start<S: Schema>(model: &str, port_of: impl Fn(&S) -> u16) -> Started<S> {
    init_logging();
    let options = cli::Options::parse();
    let path: PathBuf = options.flash_path(model);
    let flash = flash::FileFlash::open(&path).unwrap_or_else(|e| fail(&format!("flash image {}: {e}", path.display())));
    let store =
        SettingsStore::open(flash, const { SettingsStore::<flash::FileFlash, S>::config(0..flash::SIZE as u32) }).await;
    let addr = options.listen_addr(port_of(store.get()));
    let listener = modbus::bind(addr).unwrap_or_else(|e| fail(&format!("cannot listen on {addr}: {e}")));
    let local = listener.get_ref().local_addr().map_or(addr, |a| a);
    log::info!("{model} simulated module: settings in {}", path.display());
    log::info!("modbus: listening on {local}");
    Started { options, store, listener: Box::leak(Box::new(listener)) }
}

/// Exits the process with a clear message and status 2 (start-up errors).
pub fn fail(message: &str) -> ! {
    eprintln!("error: {message}");
    std::process::exit(2)
}
