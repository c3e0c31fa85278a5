//! Identity registers common to both modules (spec §2.1, §3.2).

pub use remodaq_protocol::identity::*;

/// The value of an identity register of module `name`, if `addr` is one.
pub fn read(name: u16, addr: u16) -> Option<u16> {
    match addr {
        REG_NAME => Some(name),
        REG_VERSION => Some(FIRMWARE_VERSION),
        _ => None,
    }
}
