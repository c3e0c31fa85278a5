//! The RemoDAQ-8350 firmware image: the module (`remodaq-8350`) on the board chosen at build
//! time. On a PC it is the simulated module (`--help`); on `thumbv7em-none-eabihf` it is the
//! firmware of the STM32 board (default) or of the QEMU board (`--no-default-features
//! --features board-qemu`).
#![cfg_attr(target_os = "none", no_std, no_main)]

/// The module of this image.
type Module = remodaq_8350::M8350;

include!("../../boards/image.rs");

/// The 8350's I/O loop (input capture drained every 2 ms, output pattern refilled every 6.4 ms),
/// on the board's realtime executor: it preempts the Modbus, discovery and update tasks, so an
/// update's signature check cannot make the outputs run dry (docs/design.md, "Three executors").
#[embassy_executor::task]
async fn application(state: &'static <Module as remodaq_shared::board::Module>::State, io: Io) -> ! {
    use remodaq_shared::board::{Board as _, RunsRealtime as _};
    Module::run_realtime(io, state, Board::app_alive).await
}

fn spawn_application(spawner: Spawner, app: &'static Running, io: Io) {
    use remodaq_shared::board::Board as _;
    remodaq_shared::app::spawn_send(Board::realtime(spawner), application(app.state(), io), "app");
}
