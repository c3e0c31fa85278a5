//! Network settings of a module (spec §1.4) as stored in the settings record, and the MAC
//! address derived from the MCU unique id.

pub use remodaq_protocol::net::NetConfig;

use crate::settings::{RecordReader, RecordWriter};

/// Settings record tags used by the network settings (shared by both modules: 1..=15).
mod tag {
    pub const IP: u8 = 1;
    pub const MASK: u8 = 2;
    pub const GATEWAY: u8 = 3;
    pub const PORT: u8 = 4;
    pub const HTTP_PORT: u8 = 10;
}

/// The web console's port from the factory (issue #25: port 80).
pub const HTTP_PORT: u16 = 80;

/// The web console's port in a settings record.
pub fn encode_http_port(port: u16, w: &mut RecordWriter<'_>) {
    w.put_u16(tag::HTTP_PORT, port);
}

/// The web console's port of a settings record; the factory port if absent (a record of an
/// image before it) or 0.
pub fn decode_http_port(r: &RecordReader<'_>) -> u16 {
    r.u16(tag::HTTP_PORT).filter(|p| *p != 0).unwrap_or(HTTP_PORT)
}

/// The network settings' fields in a settings record.
pub trait NetRecord: Sized {
    /// Writes the fields into a settings record.
    fn encode(&self, w: &mut RecordWriter<'_>);
    /// Reads the fields of a settings record; factory defaults if absent or not valid.
    fn decode(r: &RecordReader<'_>) -> Self;
}

impl NetRecord for NetConfig {
    fn encode(&self, w: &mut RecordWriter<'_>) {
        w.put(tag::IP, &self.ip);
        w.put(tag::MASK, &self.mask);
        w.put(tag::GATEWAY, &self.gateway);
        w.put_u16(tag::PORT, self.port);
    }

    fn decode(r: &RecordReader<'_>) -> Self {
        let f = Self::FACTORY;
        let cfg = Self {
            ip: r.array(tag::IP).unwrap_or(f.ip),
            mask: r.array(tag::MASK).unwrap_or(f.mask),
            gateway: r.array(tag::GATEWAY).unwrap_or(f.gateway),
            port: r.u16(tag::PORT).unwrap_or(f.port),
        };
        if cfg.is_valid() {
            cfg
        } else {
            f
        }
    }
}

/// A stable, locally administered, unicast MAC address from the 96-bit MCU unique id.
pub fn mac_from_uid(uid: &[u8; 12]) -> [u8; 6] {
    // FNV-1a over the id spreads the lot/wafer/position fields over all 46 free bits.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in uid {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0000_0100_0000_01B3);
    }
    let b = h.to_be_bytes();
    [(b[2] & 0xFC) | 0x02, b[3], b[4], b[5], b[6], b[7]]
}

/// Set once new network settings were stored since the start (by discovery or the web
/// console): they are in force only after a restart.
pub static NETWORK_STORED: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mac_is_local_unicast_and_stable() {
        let a = mac_from_uid(&[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]);
        assert_eq!(a, mac_from_uid(&[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]));
        assert_eq!(a[0] & 0x03, 0x02);
        assert_ne!(a, mac_from_uid(&[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 13]));
    }
}
