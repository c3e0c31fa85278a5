//! RemoDAQ-8300 module runtime (`no_std`, host tested): what every network service and every
//! board uses. The board contract ([`board`], traits only) and the start-up path ([`app`]); the
//! module and its settings store ([`module`], [`settings`], [`flash`]); the Modbus data model a
//! module implements ([`modbus`]); diagnostics, health and logging; the password, nonce and
//! access-control state; the identity, the network settings and the socket plan. The services
//! are crates of their own (`services/`), and so is the embassy-net part (`shared/net`).
#![no_std]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

pub mod fmt;

pub mod access;
pub mod app;
pub mod board;
pub mod budget;
pub mod clock;
pub mod diagnostics;
pub mod flash;
pub mod health;
pub mod identity;
pub mod json;
pub mod modbus;
pub mod module;
pub mod mqtt;
pub mod net;
pub mod nonces;
pub mod offload;
pub mod password;
pub mod points;
pub mod ram_flash;
pub mod settings;
pub mod sockets;
#[cfg(feature = "web")]
pub mod upload;

pub use remodaq_protocol as protocol;
