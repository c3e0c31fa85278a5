//! Modbus write requests as PDUs ([`Pdu`]), built by the services that write through the PDU
//! engine ([`handle_pdu`](super::handle_pdu)) as a Modbus master would: the web console's API
//! and MQTT's commands, so that every write meets the same checks.

use remodaq_protocol::words_low_first;

/// A Modbus write request PDU (at most code 16 with two registers).
pub struct Pdu {
    bytes: [u8; 10],
    len: usize,
}

impl Pdu {
    /// The request's bytes, from the function code.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes[..self.len]
    }

    /// Code 05: one coil.
    pub fn bit(addr: u16, on: bool) -> Self {
        let [a, b] = addr.to_be_bytes();
        Self { bytes: [0x05, a, b, if on { 0xFF } else { 0 }, 0, 0, 0, 0, 0, 0], len: 5 }
    }

    /// Code 06: one register.
    pub fn word(addr: u16, value: u16) -> Self {
        let ([a, b], [c, d]) = (addr.to_be_bytes(), value.to_be_bytes());
        Self { bytes: [0x06, a, b, c, d, 0, 0, 0, 0, 0], len: 5 }
    }

    /// Code 16: a 32-bit value in two registers, low word first (spec §3.2), in one request
    /// (all or nothing).
    pub fn long(addr: u16, value: u32) -> Self {
        let [low, high] = words_low_first(value);
        let ([a, b], [lh, ll], [hh, hl]) = (addr.to_be_bytes(), low.to_be_bytes(), high.to_be_bytes());
        Self { bytes: [0x10, a, b, 0, 2, 4, lh, ll, hh, hl], len: 10 }
    }
}
