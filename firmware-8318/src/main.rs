//! The RemoDAQ-8318 firmware image: the module (`remodaq-8318`) on the board chosen at build
//! time. On a PC it is the simulated module (`--help`); on `thumbv7em-none-eabihf` it is the
//! firmware of the STM32 board (default) or of the QEMU board (`--no-default-features
//! --features board-qemu`).
#![cfg_attr(target_os = "none", no_std, no_main)]

/// The module of this image.
type Module = remodaq_8318::M8318;

include!("../../boards/image.rs");

/// The 8318's acquisition, on the main executor: it takes the register map's lock (the settings
/// in force, the values it publishes).
#[embassy_executor::task]
async fn application(app: &'static Running, io: Io) -> ! {
    app.run(io).await
}

fn spawn_application(spawner: Spawner, app: &'static Running, io: Io) {
    remodaq_shared::app::spawn(spawner, application(app, io), "app");
}
