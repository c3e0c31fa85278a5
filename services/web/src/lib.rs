//! The web console (issue #25, docs/web.md): its pages (built into flash by `build.rs`), its
//! sessions ([`sessions`], plain logic), its HTTP service and JSON API on picoserve
//! ([`service`], with the settings ([`settings`]) and firmware upload ([`firmware`]) resources),
//! and its transport on embassy-net sockets ([`embassy`], feature `embassy-net`; the host board
//! has its own).
#![no_std]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

#[cfg(feature = "embassy-net")]
pub mod embassy;
pub mod firmware;
#[cfg(feature = "mqtt")]
pub mod mqtt;

pub mod service;
pub mod sessions;
pub mod settings;

pub use sessions::*;
