//! MBAP framing (spec §1.1): a stream of bytes is cut into frames by the header's length field.
//!
//! - protocol id != 0: the frame is discarded, the connection kept;
//! - length < 2 or > 254: the stream is out of sync, the connection must be closed;
//! - any unit id is accepted and echoed.

use remodaq_shared::modbus::pdu::MAX_PDU;

/// MBAP header length (transaction id, protocol id, length, unit id).
pub const MBAP_LEN: usize = 7;
/// Largest Modbus/TCP frame: header + 253-byte PDU.
pub const MAX_ADU: usize = MBAP_LEN + MAX_PDU;

/// The MBAP header of a request, echoed in its response.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Header {
    /// Transaction id, echoed.
    pub transaction: u16,
    /// Unit id, echoed.
    pub unit: u8,
}

/// What the front of a receive buffer holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Frame {
    /// Not enough bytes yet to decide.
    Incomplete,
    /// A request of `len` bytes (header + PDU) whose PDU starts at [`MBAP_LEN`].
    Request {
        /// The header to echo.
        header: Header,
        /// Total frame length.
        len: usize,
    },
    /// A complete frame with a protocol id other than 0: drop its `len` bytes.
    Discard {
        /// Total frame length.
        len: usize,
    },
    /// The length field is out of bounds: the stream cannot be resynchronised.
    Desync,
}

/// Classifies the bytes at the front of `buf`.
#[inline]
pub fn classify(buf: &[u8]) -> Frame {
    let Some(&[t0, t1, p0, p1, l0, l1]) = buf.first_chunk::<6>() else { return Frame::Incomplete };
    let length = usize::from(u16::from_be_bytes([l0, l1]));
    if !(2..=MAX_PDU + 1).contains(&length) {
        return Frame::Desync;
    }
    let len = 6 + length;
    // A complete frame has at least 8 bytes (length >= 2), so the unit id is there.
    let (Some(&unit), true) = (buf.get(6), buf.len() >= len) else { return Frame::Incomplete };
    if p0 | p1 != 0 {
        return Frame::Discard { len };
    }
    Frame::Request { header: Header { transaction: u16::from_be_bytes([t0, t1]), unit }, len }
}

/// Writes the response header for a PDU of `pdu_len` bytes.
#[inline]
pub fn write_header(out: &mut [u8; MBAP_LEN], header: Header, pdu_len: usize) {
    let [t0, t1] = header.transaction.to_be_bytes();
    let [l0, l1] = ((pdu_len + 1) as u16).to_be_bytes();
    *out = [t0, t1, 0, 0, l0, l1, header.unit];
}
