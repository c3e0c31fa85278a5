//! The PC side of the RemoDAQ-8300 protocols, shared by the `remodaq` CLI and the
//! `remodaq-utility` window: discovery and configuration (UDP), Modbus/TCP reads and writes,
//! firmware update, and the error classes every failure is given.

mod error;
pub mod ifaces;
pub mod lan;
pub mod modbus;
pub mod reading;
pub mod settings;
pub mod update;
pub mod web;

pub use error::Error;
