//! RemoDAQ-8350 firmware. Built for `thumbv7em-none-eabihf` it is the module's firmware on the
//! STM32 board; built for the host it is the same application on the host board (a simulated
//! module). Everything board-specific is in the board file chosen below.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg_attr(target_os = "none", path = "board_stm32.rs")]
#[cfg_attr(not(target_os = "none"), path = "board_host.rs")]
mod board;

#[embassy_executor::main]
async fn main(spawner: embassy_executor::Spawner) {
    board::run(spawner).await;
}
