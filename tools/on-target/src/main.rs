//! On-target tests of a board, as a firmware image that runs them at start-up and reports.
//!
//! - STM32 board (default), on a Nucleo-F429ZI through probe-rs:
//!   `cargo run --release --target thumbv7em-none-eabihf -p on-target`. Needs, besides the
//!   ST-LINK USB cable: an Ethernet cable to a switch (PHY link), an AD7124-8 wired as in the
//!   README (AD7124 id over SPI), and a jumper from DO0 (PF12) to DI0 (PE2) (header pins: the
//!   Nucleo-144 user manual, UM1974), so the outputs and the inputs test each other. The live settings are kept: the
//!   test saves them, exercises the store, and writes them back.
//! - QEMU board: `scripts/qemu on-target` (the test command runs it); the checks that need
//!   hardware the machine does not have are not built.
//!
//! Each check prints `on-target NAME ... ok` or `... FAILED: why`, then one line
//! `on-target: N passed, N failed`; the program exits (semihosting) with status 0 only if all
//! passed.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("on-target runs on a board: see the README (Nucleo) or scripts/qemu on-target");
}

#[cfg(all(target_os = "none", feature = "board-stm32", feature = "board-qemu"))]
compile_error!("choose one board: `board-stm32` (default) or `--no-default-features --features board-qemu`");

#[cfg(target_os = "none")]
mod checks;

#[cfg(target_os = "none")]
use embassy_executor::Spawner;

#[cfg(all(target_os = "none", not(feature = "board-qemu")))]
#[embassy_executor::main]
async fn main(spawner: Spawner) {
    checks::run(spawner).await
}

#[cfg(all(target_os = "none", feature = "board-qemu"))]
#[cortex_m_rt::entry]
fn main() -> ! {
    remodaq_board_qemu::executor::run(|_, main| remodaq_shared::app::spawn(main, main_task(main), "main"))
}

#[cfg(all(target_os = "none", feature = "board-qemu"))]
#[embassy_executor::task]
async fn main_task(spawner: Spawner) {
    checks::run(spawner).await
}
