//! The PC's network interfaces (issue #26): a search goes out on every IPv4 interface that is
//! up, each through a socket of its own bound to that interface, as the vendor's utility shows
//! one `Host (address)` node per interface (manuals, Figure 3.4). A limited broadcast
//! (255.255.255.255) through an unbound socket leaves by the default route's interface only, or
//! fails ("Network is unreachable") when no interface has a default route.
//!
//! How a socket is tied to its interface:
//! - Linux and macOS: bound to the device (`SO_BINDTOIFINDEX` / `IP_BOUND_IF`, socket2's
//!   `bind_device_by_index_v4`) and to 0.0.0.0, so that it also receives the answers a module on
//!   another subnet broadcasts back (docs/discovery.md); without the privilege for that (Linux
//!   before 5.7 needs CAP_NET_RAW), bound to the interface's address, which receives unicast
//!   answers only;
//! - Windows: bound to the interface's address (a broadcast then leaves by that interface, and
//!   broadcasts arriving on it are delivered to the socket).

use std::net::{Ipv4Addr, SocketAddrV4};

use socket2::{Domain, Protocol, Socket, Type};
use tokio::net::UdpSocket;

use crate::Error;

/// One IPv4 address of an interface of this PC.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Iface {
    /// The interface's name (`eth0`; on Windows the adapter's friendly name).
    pub name: String,
    /// Its address.
    pub ip: Ipv4Addr,
    /// Its prefix length.
    pub prefix: u8,
    /// Its index, where the system gives one.
    pub index: Option<u32>,
}

impl Iface {
    /// `name (address)`, as the search shows it.
    pub fn label(&self) -> String {
        format!("{} ({})", self.name, self.ip)
    }
}

/// The IPv4 interfaces that are up (operationally: with a carrier), without loopback and
/// point-to-point links (VPN tunnels: no module is there, and a search should not leak into
/// them); only those whose name or address is `only`, when given (loopback included then).
pub fn list(only: Option<&str>) -> Result<Vec<Iface>, Error> {
    let all = if_addrs::get_if_addrs().map_err(|e| Error::Other(format!("cannot list the network interfaces: {e}")))?;
    let named = |i: &if_addrs::Interface| only.is_some_and(|o| i.name == o || i.ip().to_string() == o);
    let mut out: Vec<Iface> = all
        .into_iter()
        .filter(|i| named(i) || (!i.is_loopback() && i.is_oper_up() && !i.is_p2p()))
        .filter_map(|i| match i.addr {
            if_addrs::IfAddr::V4(v4) => Some(Iface { name: i.name, ip: v4.ip, prefix: v4.prefixlen, index: i.index }),
            if_addrs::IfAddr::V6(_) => None,
        })
        .collect();
    if let Some(only) = only {
        out.retain(|i| i.name == only || i.ip.to_string() == only);
        if out.is_empty() {
            return Err(Error::Other(format!(
                "no IPv4 interface that is up is named or addressed `{only}` (see the interfaces: ip addr, ipconfig)"
            )));
        }
    }
    Ok(out)
}

/// A UDP socket, broadcast enabled, that sends by `iface` and receives what arrives on it.
pub fn socket(iface: &Iface) -> Result<UdpSocket, Error> {
    let fail = |what: &str, e: std::io::Error| Error::Other(format!("{}: cannot {what}: {e}", iface.label()));
    let socket = Socket::new(Domain::IPV4, Type::DGRAM, Some(Protocol::UDP)).map_err(|e| fail("open a socket", e))?;
    socket.set_broadcast(true).map_err(|e| fail("enable broadcast", e))?;
    socket.set_nonblocking(true).map_err(|e| fail("make the socket non-blocking", e))?;
    let local = if bound_to_device(&socket, iface) { Ipv4Addr::UNSPECIFIED } else { iface.ip };
    socket.bind(&SocketAddrV4::new(local, 0).into()).map_err(|e| fail("bind a socket", e))?;
    UdpSocket::from_std(socket.into()).map_err(|e| fail("use the socket", e))
}

/// Binds `socket` to `iface`'s device where the system can; whether it did.
#[cfg(any(target_os = "linux", target_os = "android", target_os = "macos", target_os = "ios"))]
fn bound_to_device(socket: &Socket, iface: &Iface) -> bool {
    let Some(index) = iface.index.and_then(std::num::NonZeroU32::new) else { return false };
    socket.bind_device_by_index_v4(Some(index)).is_ok()
}

/// Windows (and other systems): the socket is bound to the interface's address instead.
#[cfg(not(any(target_os = "linux", target_os = "android", target_os = "macos", target_os = "ios")))]
fn bound_to_device(_socket: &Socket, _iface: &Iface) -> bool {
    false
}
