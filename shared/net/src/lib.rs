//! The module runtime's network part on embassy-net, for every board that runs it (the STM32 and
//! QEMU boards): the board's running network ([`EmbassyNet`], the board contract's [`Network`]),
//! the SYN backlog between the Ethernet driver and the stack ([`backlog`]) with the keyed
//! initial sequence numbers of every TCP connection ([`isn`]), and the socket
//! helpers every service's embassy-net transport uses (accept through a backlog, close, reset,
//! the peer). It knows no service: the socket plan it sizes the stack by is the runtime's
//! (`remodaq_shared::sockets`).
#![no_std]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

pub mod backlog;
pub mod isn;

use core::future::{poll_fn, Future};
use core::pin::pin;

use embassy_net::tcp::{AcceptError, State, TcpSocket};
use embassy_net::{IpAddress, IpEndpoint, Stack};
use embassy_time::{with_timeout, Duration};
use remodaq_shared::board::{Effect, Effects, Network};
use remodaq_shared::sockets::MODBUS_SOCKETS;
use remodaq_shared::warn;

use crate::backlog::{Gate, Peer, HANDSHAKE_TIMEOUT_MS};

/// How long a connection the peer closed may take to finish closing before it is reset.
const CLOSE_WAIT: Duration = Duration::from_millis(100);

/// The stack's sockets: the Modbus connection tasks, discovery's, update, one of slack, the
/// web console's connections and MQTT's (its broker's, SNTP's), in an image that has them.
pub const STACK_SOCKETS: usize =
    MODBUS_SOCKETS + remodaq_shared::sockets::DISCOVERY_SOCKETS + 2 + WEB_SOCKETS + MQTT_SOCKETS;
#[cfg(feature = "mqtt")]
const MQTT_SOCKETS: usize = 2;
#[cfg(not(feature = "mqtt"))]
const MQTT_SOCKETS: usize = 0;
#[cfg(feature = "web")]
const WEB_SOCKETS: usize = remodaq_shared::sockets::WEB_CONNECTIONS;
#[cfg(not(feature = "web"))]
const WEB_SOCKETS: usize = 0;

/// A board's running network on an embassy-net stack: the stack, the Modbus/TCP port, and the
/// board's identify and restart (what discovery asks for).
pub struct EmbassyNet<E> {
    /// The stack.
    pub stack: Stack<'static>,
    /// The Modbus/TCP port.
    pub port: u16,
    /// The board's identify and restart.
    pub effects: E,
}

impl<E: Effects> Network for EmbassyNet<E> {
    /// The link (the PHY's, through the driver) and an IPv4 address. `is_config_up` alone is
    /// no test: with a static address it holds from the stack's construction (only DHCP clears
    /// it), so an image that broke the PHY or MAC path would confirm itself.
    fn is_up(&self) -> bool {
        self.stack.is_link_up() && self.stack.config_v4().is_some()
    }

    async fn restart(&self) -> ! {
        self.effects.apply(Effect::Restart).await;
        core::future::pending().await
    }
}

/// Accepts a connection on `port` through its backlog (`gate`: [`backlog::MODBUS_BACKLOG`], or the web
/// console's): the gate
/// learns the socket listens only once it does (the accept's first poll puts it in LISTEN),
/// and which client it took. A handshake that does not complete within
/// [`HANDSHAKE_TIMEOUT_MS`] (smoltcp would wait for ever: a SYN from a host gone, or spoofed)
/// ends it with `ConnectionReset`.
pub async fn accept(socket: &mut TcpSocket<'_>, port: u16, gate: &dyn Gate) -> Result<(), AcceptError> {
    socket.set_timeout(Some(Duration::from_millis(HANDSHAKE_TIMEOUT_MS)));
    let mut listening = false;
    let result = {
        let mut accepting = pin!(socket.accept(port));
        poll_fn(|cx| {
            let poll = accepting.as_mut().poll(cx);
            if poll.is_pending() && !listening {
                listening = true;
                gate.listening(port);
            }
            poll
        })
        .await
    };
    socket.set_timeout(None);
    // smoltcp ends a handshake that timed out in CLOSED, which the accept takes for done.
    let result = result.and_then(|()| match socket.state() {
        State::Closed => Err(AcceptError::ConnectionReset),
        _ => Ok(()),
    });
    if listening {
        gate.accepted(result.ok().and_then(|()| client(socket)));
    }
    result
}

/// Accepts one connection on `port` (the update service): a handshake that never
/// completes (a SYN from a forged or vanished host) must not hold the port, smoltcp would wait
/// for ever. Whether a client is connected.
pub async fn accept_one(socket: &mut TcpSocket<'_>, port: u16, service: &str) -> bool {
    socket.set_timeout(Some(Duration::from_millis(HANDSHAKE_TIMEOUT_MS)));
    let accepted = socket.accept(port).await;
    socket.set_timeout(None);
    if let Err(e) = accepted {
        warn!("{}: accept failed: {:?}", service, e);
        return false;
    }
    // CLOSED: the handshake timed out.
    socket.state() != State::Closed
}

/// Sends our FIN after the last answer, waiting for it at most [`CLOSE_WAIT`].
pub async fn close(socket: &mut TcpSocket<'_>) {
    socket.close();
    let _ = with_timeout(CLOSE_WAIT, socket.flush()).await;
}

/// Resets the connection (nothing, if it is closed already), and waits, at most
/// [`CLOSE_WAIT`], for the RST to leave: a socket dropped at once leaves the stack before it
/// sends it, and its peer learns only from the RST answering its next request.
pub async fn reset(socket: &mut TcpSocket<'_>) {
    socket.abort();
    let _ = with_timeout(CLOSE_WAIT, socket.flush()).await;
}

/// The client: IPv4 address and port, if connected.
pub fn client(socket: &TcpSocket<'_>) -> Option<Peer> {
    match socket.remote_endpoint()? {
        IpEndpoint { addr: IpAddress::Ipv4(ip), port } => Some(Peer { ip: ip.octets(), port }),
    }
}

/// The client's IPv4 address (0.0.0.0 if unknown).
pub fn peer(socket: &TcpSocket<'_>) -> [u8; 4] {
    client(socket).map_or([0; 4], |client| client.ip)
}
