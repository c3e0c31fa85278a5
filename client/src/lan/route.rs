//! Where a configuration command goes (security review finding 4): unicast to the address the
//! module answered from, by the interface it answered on, and only that address's answers
//! taken; by broadcast only to a module on another subnet than the PC's interface.

use std::net::{Ipv4Addr, SocketAddr};
use std::time::Instant;

use tokio::net::UdpSocket;

use crate::ifaces::Iface;
use crate::Error;

/// The length and source of a received datagram; `None` for a receive error, which ends nothing: on
/// Windows an ICMP "port unreachable" for an earlier datagram (WSAECONNRESET) or an oversized
/// datagram (WSAEMSGSIZE) surface as errors of the next receive, and other modules may still
/// answer before the deadline.
pub(super) fn datagram(received: std::io::Result<(usize, SocketAddr)>) -> Option<(usize, SocketAddr)> {
    received.ok()
}

/// Whether `to` is the limited broadcast address (the search and commands then go out on
/// every interface, or on `--interface`).
pub(super) fn is_broadcast(to: SocketAddr) -> bool {
    to.ip() == std::net::IpAddr::V4(Ipv4Addr::BROADCAST)
}

/// Where a command for a module goes, and by which socket.
pub(super) struct Route {
    pub(super) socket: UdpSocket,
    /// The module's own address (its answers must come from there), or the broadcast address
    /// for a module on another subnet than the interface it answered on.
    pub(super) target: SocketAddr,
}

impl Route {
    pub(super) fn is_broadcast(&self) -> bool {
        is_broadcast(self.target)
    }
}

/// Of a search for one module (its MAC written `mac`), the interfaces it answered on with
/// the addresses it answered from: the interface a command goes by, and where to (see
/// `super::via`); `None` when it did not answer. A module that answered on more than one
/// interface, or from more than one address, is refused: a host could answer a search with any
/// module's MAC and draw the command, its proof of the password among it, to itself.
pub(super) fn choose(
    to: SocketAddr,
    mac: &str,
    on: &[(Option<Iface>, Vec<SocketAddr>)],
) -> Result<Option<(Option<Iface>, SocketAddr)>, Error> {
    let (iface, from) = match on {
        [] => return Ok(None),
        [(iface, from)] => (iface, from),
        several => {
            let names: Vec<String> = several.iter().filter_map(|(i, _)| i.as_ref().map(Iface::label)).collect();
            return Err(Error::Other(format!(
                "module {mac} answered on {}: choose one with --interface (another host may be answering for it)",
                names.join(" and ")
            )));
        }
    };
    let [from] = from.as_slice() else {
        let addresses: Vec<String> = from.iter().map(|f| f.ip().to_string()).collect();
        return Err(Error::Other(format!(
            "module {mac} answered from {}: another host may be answering for it; name the module's address",
            addresses.join(" and ")
        )));
    };
    Ok(Some((iface.clone(), target_of(to, iface.as_ref(), *from))))
}

/// Where a command goes for a module whose search answer (sent to the broadcast address `to`)
/// came `from`, on `iface`: unicast to that address (the port `to` names) when it is in the
/// interface's subnet (or the PC has no interface to tell by), else the broadcast address.
fn target_of(to: SocketAddr, iface: Option<&Iface>, from: SocketAddr) -> SocketAddr {
    let near = match (iface, from.ip()) {
        (Some(iface), std::net::IpAddr::V4(ip)) => same_subnet(iface, ip),
        (Some(_), std::net::IpAddr::V6(_)) => false,
        (None, _) => true,
    };
    if near {
        SocketAddr::new(from.ip(), to.port())
    } else {
        to
    }
}

/// Whether `ip` is in `iface`'s subnet.
fn same_subnet(iface: &Iface, ip: Ipv4Addr) -> bool {
    let mask = u32::MAX.checked_shl(32 - u32::from(iface.prefix.min(32))).unwrap_or(0);
    u32::from(iface.ip) & mask == u32::from(ip) & mask
}

/// Waits for the first datagram that `accept` takes; on a unicast route, from the module's
/// address only (any other source's is dropped unread).
pub(super) async fn receive<T>(
    route: &Route,
    deadline: Instant,
    what: impl Fn() -> String,
    mut accept: impl FnMut(&[u8]) -> Option<T>,
) -> Result<T, Error> {
    let mut rx = [0u8; 512];
    loop {
        let received = tokio::time::timeout_at(deadline.into(), route.socket.recv_from(&mut rx)).await;
        let Ok(received) = received else { return Err(Error::Timeout(what())) };
        let Some((n, from)) = datagram(received) else { continue };
        if !route.is_broadcast() && from.ip() != route.target.ip() {
            continue;
        }
        if let Some(out) = accept(&rx[..n]) {
            return Ok(out);
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    fn iface(ip: [u8; 4], prefix: u8) -> Iface {
        Iface { name: "pc0".into(), ip: Ipv4Addr::from(ip), prefix, index: None }
    }

    /// Security review finding 4: once the module's address is known, a command goes to it
    /// alone; by broadcast only for a module on another subnet than the interface.
    #[test]
    fn a_command_goes_unicast_unless_the_module_is_on_a_foreign_subnet() {
        let to = SocketAddr::from(([255, 255, 255, 255], 8300));
        let pc0 = iface([190, 5, 200, 102], 24);
        let module = SocketAddr::from(([190, 5, 200, 110], 8300));
        assert_eq!(target_of(to, Some(&pc0), module), module, "in the subnet: unicast");
        // A factory-fresh module at 192.168.0.1 seen from 190.5.200.102/24 (the manuals' first
        // contact): only broadcast reaches it.
        let fresh = SocketAddr::from(([192, 168, 0, 1], 8300));
        assert_eq!(target_of(to, Some(&pc0), fresh), to, "foreign subnet: broadcast");
        assert_eq!(
            target_of(to, Some(&iface([10, 0, 0, 2], 8)), SocketAddr::from(([10, 200, 1, 1], 8300))).ip(),
            std::net::IpAddr::V4(Ipv4Addr::new(10, 200, 1, 1))
        );
        assert_eq!(target_of(to, Some(&iface([10, 0, 0, 2], 32)), SocketAddr::from(([10, 0, 0, 3], 8300))), to, "/32");
        assert_eq!(target_of(to, None, module), module, "no interface to tell by: where it answered from");
    }

    /// On a unicast route, an answer from any other address is dropped unread, even one the
    /// exchange would take (a host that saw the request and answers first).
    #[tokio::test]
    async fn a_unicast_route_takes_answers_from_the_module_only() {
        let module = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let forger = std::net::UdpSocket::bind("127.0.0.2:0").unwrap();
        let pc = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let at = pc.local_addr().unwrap();
        let route = Route { socket: pc, target: module.local_addr().unwrap() };
        forger.send_to(b"forged", at).unwrap();
        module.send_to(b"genuine", at).unwrap();
        let deadline = Instant::now() + Duration::from_secs(2);
        let got = receive(&route, deadline, String::new, |d| Some(d.to_vec())).await.unwrap();
        assert_eq!(got, b"genuine");
        // A broadcast route (a module on a foreign subnet) cannot tell: it takes the first.
        let pc = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let at = pc.local_addr().unwrap();
        let route = Route { socket: pc, target: SocketAddr::from(([255, 255, 255, 255], 8300)) };
        forger.send_to(b"forged", at).unwrap();
        let got = receive(&route, deadline, String::new, |d| Some(d.to_vec())).await.unwrap();
        assert_eq!(got, b"forged");
    }
}
