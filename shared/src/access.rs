//! Access control on the module side (extensions §4): the Modbus write allow-list in the
//! settings record, and the rule a register map applies to each request.

pub use remodaq_protocol::access::*;

use crate::modbus::Exception;
use crate::settings::{RecordReader, RecordWriter};

/// Settings record tag of the allow-list (shared by both modules: 1..=15).
const TAG: u8 = 7;

/// Writes the allow-list into a settings record.
pub fn encode(list: &AllowList, w: &mut RecordWriter<'_>) {
    let mut buf = [0u8; ENCODED_MAX];
    let n = list.encode(&mut buf);
    w.put(TAG, &buf[..n]);
}

/// Reads the allow-list of a settings record; empty (factory) if absent or malformed.
pub fn decode(r: &RecordReader<'_>) -> AllowList {
    r.get(TAG).and_then(AllowList::decode).unwrap_or(AllowList::EMPTY)
}

/// Whether a Modbus function code writes (05, 06, 15, 16).
pub fn is_write(function: u8) -> bool {
    use crate::modbus::pdu::{
        WRITE_MULTIPLE_COILS, WRITE_MULTIPLE_REGISTERS, WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER,
    };
    matches!(function, WRITE_SINGLE_COIL | WRITE_SINGLE_REGISTER | WRITE_MULTIPLE_COILS | WRITE_MULTIPLE_REGISTERS)
}

/// The rule of extensions §4: a write request from a client outside every listed network
/// answers exception 01; reads, and anything from an allowed client, go on.
pub fn admit(list: &AllowList, from: [u8; 4], function: u8) -> Result<(), Exception> {
    if is_write(function) && !list.allows(from) {
        crate::diagnostics::DIAGNOSTICS.security(crate::diagnostics::Security::AccessRefusal, from);
        return Err(Exception::IllegalFunction);
    }
    Ok(())
}
