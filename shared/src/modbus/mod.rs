//! The Modbus data model a module implements: the register-map abstraction ([`map`]), the PDU
//! engine over it ([`pdu`]), write requests for it ([`request`]) and the exception codes
//! ([`exception`]). The Modbus/TCP server (its
//! framing and connections) is a service of its own, `remodaq-modbus`.

pub mod exception;
pub mod map;
pub mod pdu;
pub mod request;

pub use exception::Exception;
pub use map::{Access, RegisterMap, Table, WriteValues};
pub use pdu::{handle_pdu, MAX_PDU};
pub use request::Pdu;
