//! The RemoDAQ-8318 firmware image: the module (`remodaq-8318`) on the board chosen at build
//! time. On a PC it is the simulated module (`--help`); on `thumbv7em-none-eabihf` it is the
//! firmware of the STM32 board (default) or of the QEMU board (`--no-default-features
//! --features board-qemu`).
#![cfg_attr(target_os = "none", no_std, no_main)]

/// The module of this image.
type Module = remodaq_8318::M8318;

include!("../../boards/image.rs");
