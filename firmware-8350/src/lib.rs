//! RemoDAQ-8350 module logic (`no_std`, no hardware): the digital-input engine (state,
//! counters, latches, frequency), the pulse/level output engine, the settings schema and the
//! Modbus register map (spec §3). Boards supply the flash, the input capture and the output
//! pattern path.
#![no_std]
#![warn(missing_docs)]

pub mod di;
pub mod io;
pub mod map;
pub mod pulse;
pub mod settings;

/// Module name register value (40211).
pub const MODULE_NAME: u16 = 0x8350;
/// Model string used in logs and discovery.
pub const MODEL: &str = "RemoDAQ-8350";
