//! The web console's HTTP service on picoserve (docs/web.md): the JSON API under `/api/v1/`.
//! picoserve parses the request within its buffer and timeouts; this service routes it. Every
//! read and write of the module goes through the Modbus PDU engine
//! ([`handle_pdu`](remodaq_shared::modbus::pdu::handle_pdu)) with the client's address, as a
//! Modbus request would: the same checks, the same allow-list, the same all-or-nothing commits,
//! so the API and Modbus cannot disagree. Every state-changing request needs a session and a
//! signature ([`super::Sessions::verify`]).
//!
//! Its parts: a connection's entry (`connection`), the state every resource works on and what
//! it answers (`api`), the router and the checks of a request's head (`router`), and the
//! resources: logging in (`login`), the registers and coils (`registers`) and the module's
//! named resources (`values`); the settings and the firmware upload are the crate's
//! [`settings`](crate::settings) and [`firmware`](crate::firmware).

pub(crate) mod api;
mod connection;
mod login;
mod registers;
mod router;
mod values;

pub use api::{Answer, Api, Json, SharedSessions, MAX_ANSWER, SESSIONS};
pub use connection::{
    deadline, serve_connection, write_with_buffer, Served, CONFIG, CONNECTIONS, CONNECTION_MAX, HTTP_BUFFER,
};
pub use remodaq_shared::modbus::Pdu;
pub use values::{write_request, WriteError};
