//! The RemoDAQ-8350 firmware image: the module (`remodaq-8350`) on the board chosen at build
//! time. On a PC it is the simulated module (`--help`); on `thumbv7em-none-eabihf` it is the
//! firmware of the STM32 board (default) or of the QEMU board (`--no-default-features
//! --features board-qemu`).
#![cfg_attr(target_os = "none", no_std, no_main)]

/// The module of this image.
type Module = remodaq_8350::M8350;

include!("../../boards/image.rs");
