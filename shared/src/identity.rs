//! Identity registers common to both modules (spec §2.1, §3.2): from the protocol crate.

pub use remodaq_protocol::identity::*;
