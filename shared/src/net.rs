//! Network settings of a module (spec §1.4) and the MAC address derived from the MCU unique id.

use crate::settings::{RecordReader, RecordWriter};

/// IP settings as stored; they take effect at the next start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NetConfig {
    /// IPv4 address.
    pub ip: [u8; 4],
    /// Subnet mask (contiguous).
    pub mask: [u8; 4],
    /// Default gateway; 0.0.0.0 = none.
    pub gateway: [u8; 4],
    /// Modbus/TCP port.
    pub port: u16,
}

/// Settings record tags used by the network settings (shared by both modules: 1..=15).
mod tag {
    pub const IP: u8 = 1;
    pub const MASK: u8 = 2;
    pub const GATEWAY: u8 = 3;
    pub const PORT: u8 = 4;
}

impl NetConfig {
    /// Factory defaults: 192.168.0.1 / 255.255.255.0, no gateway, port 8000.
    pub const FACTORY: Self = Self { ip: [192, 168, 0, 1], mask: [255, 255, 255, 0], gateway: [0; 4], port: 8000 };

    /// Prefix length of the mask, if the mask is contiguous.
    pub fn prefix_len(&self) -> Option<u8> {
        let m = u32::from_be_bytes(self.mask);
        let len = m.leading_ones();
        (m.checked_shl(len).unwrap_or(0) == 0).then_some(len as u8)
    }

    /// A usable configuration: contiguous mask, unicast address, non-zero port.
    pub fn is_valid(&self) -> bool {
        let ip = u32::from_be_bytes(self.ip);
        self.prefix_len().is_some_and(|p| (1..=30).contains(&p))
            && ip != 0
            && self.ip[0] < 224
            && self.ip[0] != 127
            && self.port != 0
    }

    /// Whether `ip` is on this configuration's subnet.
    pub fn same_subnet(&self, ip: [u8; 4]) -> bool {
        let mask = u32::from_be_bytes(self.mask);
        u32::from_be_bytes(self.ip) & mask == u32::from_be_bytes(ip) & mask
    }

    /// Writes the fields into a settings record.
    pub fn encode(&self, w: &mut RecordWriter<'_>) {
        w.put(tag::IP, &self.ip);
        w.put(tag::MASK, &self.mask);
        w.put(tag::GATEWAY, &self.gateway);
        w.put_u16(tag::PORT, self.port);
    }

    /// Reads the fields of a settings record; factory defaults if absent or not valid.
    pub fn decode(r: &RecordReader<'_>) -> Self {
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

    #[test]
    fn masks() {
        assert_eq!(NetConfig::FACTORY.prefix_len(), Some(24));
        assert!(NetConfig::FACTORY.is_valid());
        let bad = NetConfig { mask: [255, 0, 255, 0], ..NetConfig::FACTORY };
        assert_eq!(bad.prefix_len(), None);
        assert!(!bad.is_valid());
        assert!(!NetConfig { port: 0, ..NetConfig::FACTORY }.is_valid());
    }
}
