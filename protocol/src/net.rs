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

/// An IPv4 address in dotted decimal (`192.168.1.7`), as `core::net::Ipv4Addr` reads one: four
/// numbers of 0 to 255, without signs or leading zeros. The image's own reader: core's takes
/// about 1.3 KB of flash, for IPv6 too (docs/web.md, "Budgets").
pub fn parse_ipv4(text: &str) -> Option<[u8; 4]> {
    let mut octets = [0u8; 4];
    let mut parts = text.split('.');
    for octet in &mut octets {
        let part = parts.next()?;
        let leading_zero = part.len() > 1 && part.starts_with('0');
        if part.is_empty() || part.len() > 3 || leading_zero || !part.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        *octet = part.bytes().try_fold(0u8, |n, d| n.checked_mul(10)?.checked_add(d - b'0'))?;
    }
    parts.next().is_none().then_some(octets)
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

    /// The reader agrees with core's on addresses and near-misses alike.
    #[test]
    fn ipv4_as_core_reads_it() {
        let texts = [
            "0.0.0.0",
            "255.255.255.255",
            "10.0.5.20",
            "192.168.1.7",
            "1.2.3.4",
            "256.1.1.1",
            "1.2.3",
            "1.2.3.4.5",
            "01.2.3.4",
            "1.2.3.04",
            "1.2.3.000",
            "00.1.2.3",
            "+1.2.3.4",
            "-1.2.3.4",
            "1..2.3",
            ".1.2.3",
            "1.2.3.",
            "1.2.3.4 ",
            " 1.2.3.4",
            "1.2.3.4/8",
            "a.b.c.d",
            "1.2.3.2555",
            "999.1.1.1",
            "",
            ".",
            "...",
            "1.2.3.0x1",
            "\u{661}.2.3.4",
            "1.2.3.25\u{665}",
        ];
        for text in texts {
            let core = text.parse::<core::net::Ipv4Addr>().ok().map(|a| a.octets());
            assert_eq!(parse_ipv4(text), core, "{text:?}");
        }
        for a in (0..=300u16).step_by(7) {
            let text = std::format!("{a}.{a}.0.{a}");
            let core = text.parse::<core::net::Ipv4Addr>().ok().map(|a| a.octets());
            assert_eq!(parse_ipv4(&text), core, "{text}");
        }
    }
}
