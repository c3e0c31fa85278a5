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

/// The board's executors (`remodaq_board_stm32::executor`, `remodaq_board_qemu::executor`), as
/// the firmware images run them: the checks on the main one, the background one's busy task
/// beside them (`checks::background_busy`).
#[cfg(target_os = "none")]
#[cortex_m_rt::entry]
fn main() -> ! {
    #[cfg(feature = "board-qemu")]
    use {remodaq_board_qemu::executor::run, remodaq_shared::app::spawn as spawn_main};
    #[cfg(not(feature = "board-qemu"))]
    use {remodaq_board_stm32::executor::run, remodaq_shared::app::spawn_send as spawn_main};
    run(|background, main| {
        spawn_main(main, main_task(), "main");
        remodaq_shared::app::spawn(background, checks::background_busy(), "background");
    })
}

#[cfg(target_os = "none")]
#[embassy_executor::task]
async fn main_task() {
    // SAFETY: awaited in a task of an embassy executor, with the context it polls it with (the
    // main executor is an interrupt executor, which gives a `SendSpawner` only).
    let spawner = unsafe { Spawner::for_current_executor() }.await;
    checks::run(spawner).await
}
