//! RemoDAQ-8300 common firmware library (`no_std`, host tested): Modbus/TCP, the settings
//! store, network settings, board traits and the logging shim.
#![no_std]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

pub mod fmt;

pub mod access;
pub mod backlog;
pub mod board;
pub mod diagnostics;
pub mod discovery;
#[cfg(feature = "embassy-net")]
pub mod embassy_net;
pub mod flash;
pub mod health;
pub mod identity;
pub mod modbus;
pub mod module;
pub mod net;
pub mod nonces;
pub mod password;
pub mod ram_flash;
pub mod settings;
pub mod update;
pub mod web;

pub use remodaq_protocol as protocol;
