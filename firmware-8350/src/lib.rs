//! RemoDAQ-8350 module logic (`no_std`, no hardware): settings schema and Modbus register map
//! (spec §3). Boards supply the flash and, later, the digital I/O.
#![no_std]
#![warn(missing_docs)]

pub mod map;
pub mod settings;

/// Module name register value (40211).
pub const MODULE_NAME: u16 = 0x8350;
/// Model string used in logs and discovery.
pub const MODEL: &str = "RemoDAQ-8350";
