//! The checks of the Network Settings fields, run as the user types (issue #22): what the
//! module would refuse, and what it would take but nobody could reach, are said before
//! **Setting** is pressed.

use std::net::Ipv4Addr;

use remodaq_client::lan::NetChange;
use remodaq_protocol::net::NetConfig;

/// What is wrong with one field (a key of the language tables, `crate::i18n`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Problem {
    /// Not four numbers 0-255 separated by dots.
    NotAnAddress,
    /// 0.0.0.0, 127.x, multicast (224-239), reserved (240-255) or the broadcast address.
    NotUnicast,
    /// The address is its subnet's network or broadcast address.
    HostPartAllZerosOrOnes,
    /// The mask's ones are not contiguous (255.0.255.0).
    MaskNotContiguous,
    /// A /0 or /31-/32 mask: no room for a module and a PC.
    MaskSize,
    /// The gateway is not on the module's subnet.
    GatewayOutsideSubnet,
    /// The gateway is the module's own address.
    GatewayIsModule,
    /// Not a whole number 1-65535.
    Port,
}

/// The result of checking the four fields.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Checked {
    pub ip: Option<Problem>,
    pub mask: Option<Problem>,
    pub gateway: Option<Problem>,
    pub port: Option<Problem>,
}

impl Checked {
    /// No field has a problem.
    pub fn ok(&self) -> bool {
        self.ip.is_none() && self.mask.is_none() && self.gateway.is_none() && self.port.is_none()
    }
}

fn address(text: &str) -> Result<Ipv4Addr, Problem> {
    text.trim().parse().map_err(|_| Problem::NotAnAddress)
}

/// A unicast address a module can have or route by.
fn unicast(ip: Ipv4Addr) -> Result<Ipv4Addr, Problem> {
    let first = ip.octets()[0];
    if ip.is_unspecified() || ip.is_loopback() || first >= 224 {
        Err(Problem::NotUnicast)
    } else {
        Ok(ip)
    }
}

/// Checks the fields as typed: each field's problem, and the settings when there is none.
/// An empty gateway means none (0.0.0.0).
pub fn check(ip: &str, mask: &str, gateway: &str, port: &str) -> (Checked, Option<NetChange>) {
    let mut c = Checked::default();
    let ip = address(ip).and_then(unicast).map_err(|p| c.ip = Some(p)).ok();
    let mask = address(mask)
        .and_then(|m| {
            let bits = u32::from(m);
            let ones = bits.leading_ones();
            if bits.checked_shl(ones).unwrap_or(0) != 0 {
                Err(Problem::MaskNotContiguous)
            } else if !(1..=30).contains(&ones) {
                Err(Problem::MaskSize)
            } else {
                Ok(m)
            }
        })
        .map_err(|p| c.mask = Some(p))
        .ok();
    if let (Some(a), Some(m)) = (ip, mask) {
        let host = u32::from(a) & !u32::from(m);
        if host == 0 || host == !u32::from(m) {
            c.ip = Some(Problem::HostPartAllZerosOrOnes);
        }
    }
    let gateway = if gateway.trim().is_empty() {
        Some(Ipv4Addr::UNSPECIFIED)
    } else {
        match address(gateway).and_then(unicast) {
            Err(p) => {
                c.gateway = Some(p);
                None
            }
            Ok(g) => {
                if let (Some(a), Some(m)) = (ip, mask) {
                    let m = u32::from(m);
                    let host = u32::from(g) & !m;
                    if g == a {
                        c.gateway = Some(Problem::GatewayIsModule);
                    } else if u32::from(g) & m != u32::from(a) & m {
                        c.gateway = Some(Problem::GatewayOutsideSubnet);
                    } else if host == 0 || host == !m {
                        c.gateway = Some(Problem::HostPartAllZerosOrOnes);
                    }
                }
                Some(g)
            }
        }
    };
    let port = match port.trim().parse::<u16>() {
        Ok(p) if p >= 1 => Some(p),
        _ => {
            c.port = Some(Problem::Port);
            None
        }
    };
    let change = match (c.ok(), ip, mask, gateway, port) {
        (true, Some(ip), Some(mask), Some(gateway), Some(port)) => {
            // What the module itself checks (spec §1.4) must agree.
            let net = NetConfig { ip: ip.octets(), mask: mask.octets(), gateway: gateway.octets(), port };
            net.is_valid().then_some(NetChange { ip, mask, gateway, port })
        }
        _ => None,
    };
    (c, change)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn problems(ip: &str, mask: &str, gw: &str, port: &str) -> Checked {
        check(ip, mask, gw, port).0
    }

    #[test]
    fn the_factory_settings_and_a_routed_network_pass() {
        let (c, change) = check("192.168.0.1", "255.255.255.0", "", "8000");
        assert!(c.ok());
        let change = change.unwrap();
        assert_eq!((change.gateway, change.port), (Ipv4Addr::UNSPECIFIED, 8000));
        assert!(check("10.1.2.3", "255.255.0.0", "10.1.0.1", "502").1.is_some());
        assert!(check("190.5.200.110", "255.255.255.0", "190.5.200.1", "65535").1.is_some());
    }

    #[test]
    fn each_field_says_its_own_problem() {
        assert_eq!(problems("192.168.0", "255.255.255.0", "", "8000").ip, Some(Problem::NotAnAddress));
        assert_eq!(problems("0.0.0.0", "255.255.255.0", "", "8000").ip, Some(Problem::NotUnicast));
        assert_eq!(problems("127.0.0.5", "255.0.0.0", "", "8000").ip, Some(Problem::NotUnicast));
        assert_eq!(problems("224.0.0.1", "255.255.255.0", "", "8000").ip, Some(Problem::NotUnicast));
        assert_eq!(problems("255.255.255.255", "255.255.255.0", "", "8000").ip, Some(Problem::NotUnicast));
        assert_eq!(problems("192.168.0.0", "255.255.255.0", "", "8000").ip, Some(Problem::HostPartAllZerosOrOnes));
        assert_eq!(problems("192.168.0.255", "255.255.255.0", "", "8000").ip, Some(Problem::HostPartAllZerosOrOnes));
        assert_eq!(problems("192.168.0.1", "255.0.255.0", "", "8000").mask, Some(Problem::MaskNotContiguous));
        assert_eq!(problems("192.168.0.1", "255.255.255.254", "", "8000").mask, Some(Problem::MaskSize));
        assert_eq!(problems("192.168.0.1", "0.0.0.0", "", "8000").mask, Some(Problem::MaskSize));
        assert_eq!(
            problems("192.168.0.1", "255.255.255.0", "192.168.1.1", "8000").gateway,
            Some(Problem::GatewayOutsideSubnet)
        );
        assert_eq!(
            problems("192.168.0.1", "255.255.255.0", "192.168.0.1", "8000").gateway,
            Some(Problem::GatewayIsModule)
        );
        assert_eq!(problems("192.168.0.1", "255.255.255.0", "", "0").port, Some(Problem::Port));
        assert_eq!(problems("192.168.0.1", "255.255.255.0", "", "65536").port, Some(Problem::Port));
        assert_eq!(problems("192.168.0.1", "255.255.255.0", "", "80a").port, Some(Problem::Port));
        // Nothing to store while any field is wrong.
        assert!(check("192.168.0.1", "255.255.255.0", "", "0").1.is_none());
    }
}
