//! RemoDAQ-8318 firmware. Built for `thumbv7em-none-eabihf` it is the module's firmware on the
//! STM32 board (default) or on the QEMU board (`--no-default-features --features board-qemu`);
//! built for the host it is the same application on the host board (a simulated module).
//! Everything board-specific is in the board file chosen below.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(all(target_os = "none", feature = "board-stm32", feature = "board-qemu"))]
compile_error!("choose one board: `board-stm32` (default) or `--no-default-features --features board-qemu`");

#[cfg_attr(all(target_os = "none", feature = "board-qemu"), path = "board_qemu.rs")]
#[cfg_attr(all(target_os = "none", not(feature = "board-qemu")), path = "board_stm32.rs")]
#[cfg_attr(not(target_os = "none"), path = "board_host.rs")]
mod board;

#[cfg(not(all(target_os = "none", feature = "board-qemu")))]
#[embassy_executor::main]
async fn main(spawner: embassy_executor::Spawner) {
    board::run(spawner).await;
}

/// The QEMU board runs its own executor (it sleeps with WFI: Embassy's WFE loop never sleeps
/// under QEMU).
#[cfg(all(target_os = "none", feature = "board-qemu"))]
#[cortex_m_rt::entry]
fn main() -> ! {
    remodaq_board_qemu::executor::run(|spawner| spawner.spawn(main_task(spawner).expect("one main task")))
}

#[cfg(all(target_os = "none", feature = "board-qemu"))]
#[embassy_executor::task]
async fn main_task(spawner: embassy_executor::Spawner) {
    board::run(spawner).await;
}
