//! RemoDAQ-8318 module logic (`no_std`, no hardware): settings schema and Modbus register map
//! (spec §2), input types and scaling, thermocouple maths and the acquisition cycle. Boards
//! supply the flash and the analog front end ([`acquisition::AnalogFrontEnd`]).
#![no_std]
#![warn(missing_docs)]

pub mod acquisition;
pub mod ad7124;
pub mod input;
pub mod map;
pub mod settings;
pub mod thermocouple;

/// Module name register value (40211).
pub const MODULE_NAME: u16 = 0x8318;
/// Model string used in logs and discovery.
pub const MODEL: &str = "RemoDAQ-8318";
