//! Network settings of a module (spec §1.4).

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

impl NetConfig {
    /// Factory defaults: 192.168.0.1 / 255.255.255.0, no gateway, port 8000.
    pub const FACTORY: Self =
        Self { ip: [192, 168, 0, 1], mask: [255, 255, 255, 0], gateway: [0; 4], port: crate::MODBUS_PORT };

    /// Prefix length of the mask, if the mask is contiguous.
    pub fn prefix_len(&self) -> Option<u8> {
        let m = u32::from_be_bytes(self.mask);
        let len = m.leading_ones();
        (m.checked_shl(len).unwrap_or(0) == 0).then_some(len as u8)
    }

    /// A usable configuration: contiguous mask, unicast address, a Modbus port that is neither
    /// 0 nor the firmware update service's (two services on one TCP port would take each
    /// other's connections).
    pub fn is_valid(&self) -> bool {
        let ip = u32::from_be_bytes(self.ip);
        self.prefix_len().is_some_and(|p| (1..=30).contains(&p))
            && ip != 0
            && self.ip[0] < 224
            && self.ip[0] != 127
            && self.port != 0
            && self.port != crate::update::PORT
    }

    /// Whether `ip` is on this configuration's subnet.
    pub fn same_subnet(&self, ip: [u8; 4]) -> bool {
        let mask = u32::from_be_bytes(self.mask);
        u32::from_be_bytes(self.ip) & mask == u32::from_be_bytes(ip) & mask
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masks() {
        assert_eq!(NetConfig::FACTORY.prefix_len(), Some(24));
        assert!(NetConfig::FACTORY.is_valid());
        let bad = NetConfig { mask: [255, 0, 255, 0], ..NetConfig::FACTORY };
        assert_eq!(bad.prefix_len(), None);
        assert!(!bad.is_valid());
        assert!(!NetConfig { port: 0, ..NetConfig::FACTORY }.is_valid());
        assert!(!NetConfig { port: 8301, ..NetConfig::FACTORY }.is_valid(), "the update service's port");
    }
}
