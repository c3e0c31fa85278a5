//! Access control (extensions §4): the Modbus write allow-list, up to [`MAX_NETWORKS`] IPv4
//! networks. Empty (factory): any client may write.

/// Networks an allow-list holds at most.
pub const MAX_NETWORKS: usize = 4;

/// An IPv4 network in CIDR form, kept as its network address (host bits cleared).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Network {
    /// Network address.
    pub ip: [u8; 4],
    /// Prefix length, 0..=32.
    pub prefix: u8,
}

impl Network {
    /// The network of `ip` with a `prefix`-bit mask; `None` for a prefix above 32.
    pub fn new(ip: [u8; 4], prefix: u8) -> Option<Self> {
        let mask = Self::mask_of(prefix)?;
        Some(Self { ip: (u32::from_be_bytes(ip) & mask).to_be_bytes(), prefix })
    }

    fn mask_of(prefix: u8) -> Option<u32> {
        match prefix {
            0 => Some(0),
            1..=32 => Some(u32::MAX << (32 - u32::from(prefix))),
            _ => None,
        }
    }

    /// Whether `ip` is on this network.
    pub fn contains(&self, ip: [u8; 4]) -> bool {
        let mask = Self::mask_of(self.prefix).unwrap_or(u32::MAX);
        u32::from_be_bytes(ip) & mask == u32::from_be_bytes(self.ip)
    }
}

/// `a.b.c.d/n` (a bare address is `/32`), as the utility and the web console write a network.
impl core::str::FromStr for Network {
    type Err = ();

    fn from_str(s: &str) -> Result<Self, ()> {
        let (ip, prefix) = s.split_once('/').unwrap_or((s, "32"));
        let ip = crate::net::parse_ipv4(ip).ok_or(())?;
        // A prefix is decimal digits only (u8's parse would take a sign).
        if prefix.is_empty() || prefix.len() > 2 || !prefix.bytes().all(|b| b.is_ascii_digit()) {
            return Err(());
        }
        Self::new(ip, prefix.parse().map_err(|_| ())?).ok_or(())
    }
}

impl core::fmt::Display for Network {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{}/{}", core::net::Ipv4Addr::from(self.ip), self.prefix)
    }
}

/// The Modbus write allow-list.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AllowList {
    nets: [Option<Network>; MAX_NETWORKS],
}

/// Bytes of an encoded list: a count, then 5 bytes (address, prefix) per network.
pub const ENCODED_MAX: usize = 1 + 5 * MAX_NETWORKS;

impl AllowList {
    /// The empty list (factory): every client may write.
    pub const EMPTY: Self = Self { nets: [None; MAX_NETWORKS] };

    /// A list of `nets`; `None` if there are more than [`MAX_NETWORKS`].
    pub fn of(nets: &[Network]) -> Option<Self> {
        if nets.len() > MAX_NETWORKS {
            return None;
        }
        let mut list = Self::EMPTY;
        for (slot, net) in list.nets.iter_mut().zip(nets) {
            *slot = Some(*net);
        }
        Some(list)
    }

    /// The networks, in order.
    pub fn iter(&self) -> impl Iterator<Item = Network> + '_ {
        self.nets.iter().flatten().copied()
    }

    /// True when the list is empty (writes are not restricted).
    pub fn is_empty(&self) -> bool {
        self.nets.iter().all(Option::is_none)
    }

    /// Whether a client at `ip` may write: always with an empty list, else when a listed
    /// network contains it.
    pub fn allows(&self, ip: [u8; 4]) -> bool {
        self.is_empty() || self.iter().any(|n| n.contains(ip))
    }

    /// Encodes the list into `out` (at least [`ENCODED_MAX`] bytes); returns the length.
    pub fn encode(&self, out: &mut [u8; ENCODED_MAX]) -> usize {
        let mut len = 1;
        for net in self.iter() {
            out[len..len + 4].copy_from_slice(&net.ip);
            out[len + 4] = net.prefix;
            len += 5;
        }
        out[0] = ((len - 1) / 5) as u8;
        len
    }

    /// Decodes an encoded list that is exactly `bytes`; `None` if malformed (a count above
    /// [`MAX_NETWORKS`], a prefix above 32, host bits set, a wrong length).
    pub fn decode(bytes: &[u8]) -> Option<Self> {
        let (&count, rest) = bytes.split_first()?;
        let count = usize::from(count);
        if count > MAX_NETWORKS || rest.len() != 5 * count {
            return None;
        }
        let mut list = Self::EMPTY;
        for (slot, chunk) in list.nets.iter_mut().zip(rest.chunks_exact(5)) {
            let ip = [chunk[0], chunk[1], chunk[2], chunk[3]];
            let net = Network::new(ip, chunk[4]).filter(|n| n.ip == ip)?;
            *slot = Some(net);
        }
        Some(list)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn networks_in_text() {
        assert_eq!("10.1.2.3/8".parse(), Ok(Network { ip: [10, 0, 0, 0], prefix: 8 }));
        assert_eq!("192.0.2.7".parse(), Ok(Network { ip: [192, 0, 2, 7], prefix: 32 }));
        assert_eq!("0.0.0.0/0".parse(), Ok(Network { ip: [0; 4], prefix: 0 }));
        for bad in ["192.0.2.0/33", "192.0.2.0/+8", "192.0.2.0/", "192.0.2/24", "x", "", "192.0.2.0/008"] {
            assert_eq!(bad.parse::<Network>(), Err(()), "{bad}");
        }
        let text = std::format!("{}", Network { ip: [172, 16, 0, 0], prefix: 12 });
        assert_eq!(text, "172.16.0.0/12");
    }

    #[test]
    fn cidr_matching() {
        let lan = Network::new([192, 168, 7, 99], 24).unwrap();
        assert_eq!(lan.ip, [192, 168, 7, 0], "host bits cleared");
        assert!(lan.contains([192, 168, 7, 1]) && lan.contains([192, 168, 7, 255]));
        assert!(!lan.contains([192, 168, 8, 1]));
        let one = Network::new([127, 0, 0, 2], 32).unwrap();
        assert!(one.contains([127, 0, 0, 2]) && !one.contains([127, 0, 0, 1]));
        assert!(Network::new([0; 4], 0).unwrap().contains([8, 8, 8, 8]));
        assert_eq!(Network::new([1, 2, 3, 4], 33), None);
    }

    #[test]
    fn empty_allows_all_and_round_trip() {
        assert!(AllowList::EMPTY.allows([10, 0, 0, 1]));
        let list =
            AllowList::of(&[Network::new([127, 0, 0, 2], 32).unwrap(), Network::new([10, 1, 0, 0], 16).unwrap()])
                .unwrap();
        assert!(list.allows([127, 0, 0, 2]) && list.allows([10, 1, 200, 3]));
        assert!(!list.allows([127, 0, 0, 1]));
        let mut buf = [0u8; ENCODED_MAX];
        let n = list.encode(&mut buf);
        assert_eq!(&buf[..n], &[2, 127, 0, 0, 2, 32, 10, 1, 0, 0, 16]);
        assert_eq!(AllowList::decode(&buf[..n]), Some(list));
        assert_eq!(AllowList::decode(&[0]), Some(AllowList::EMPTY));
        assert_eq!(AllowList::decode(&[5; 26]), None, "more than 4");
        assert_eq!(AllowList::decode(&[1, 1, 2, 3, 4, 40]), None, "prefix 40");
        assert_eq!(AllowList::decode(&[1, 1, 2, 3, 4]), None, "short");
        assert_eq!(AllowList::decode(&[1, 10, 0, 0, 1, 24]), None, "host bits set: not the canonical form");
        assert_eq!(AllowList::of(&[Network::new([0; 4], 0).unwrap(); 5]), None);
    }
}
