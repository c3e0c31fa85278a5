//! The Modbus/TCP service (spec §1.1): MBAP framing ([`frame`]), the connection slots and the
//! server of one connection ([`server`]) over any byte stream, and its transport on embassy-net
//! sockets ([`embassy`], feature `embassy-net`: the STM32 and QEMU boards; the host board has its
//! own). The register map and the PDU engine it serves are the module runtime's
//! (`remodaq_shared::modbus`).
#![no_std]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

#[cfg(feature = "embassy-net")]
pub mod embassy;
pub mod frame;
pub mod server;

/// The connection slots of the server, as a board's connection tasks share them.
pub type ModbusSlots = server::Slots<embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex, { server::SOCKETS }>;
