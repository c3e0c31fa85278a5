//! The network services on embassy-net sockets, for every board that runs embassy-net (the
//! STM32 and QEMU boards): the board contract's [`Network`] over a [`Stack`].

use core::future::{poll_fn, Future};
use core::pin::pin;

use embassy_net::tcp::{AcceptError, State, TcpSocket};
use embassy_net::udp::{PacketMetadata, UdpSocket};
use embassy_net::{IpAddress, IpEndpoint, Stack};
use embassy_time::{with_timeout, Duration, Timer};

use crate::backlog::{Gate, Peer, HANDSHAKE_TIMEOUT_MS, MODBUS_BACKLOG};
use crate::board::{Effects, ModbusSlots, Network, Shared};
use crate::discovery::{serve, Datagrams, Effect, Identity, MAX_DATAGRAM, PORT};
use crate::modbus::server::{serve as serve_modbus, Ended};
use crate::modbus::RegisterMap;
use crate::module::{SettingsAccess, Store};
use crate::update::{Outcome, UpdateService, UpdateTarget};
use crate::{debug, error, warn};
use embedded_storage_async::nor_flash::NorFlash;

/// How long a connection the peer closed may take to finish closing before it is reset.
const CLOSE_WAIT: Duration = Duration::from_millis(100);

/// The stack's sockets: the Modbus connection tasks, discovery, update, one of slack, and the
/// web console's connections in an image that has it.
pub const STACK_SOCKETS: usize = crate::modbus::server::SOCKETS + 3 + WEB_SOCKETS;
#[cfg(feature = "web")]
const WEB_SOCKETS: usize = crate::web::service::CONNECTIONS;
#[cfg(not(feature = "web"))]
const WEB_SOCKETS: usize = 0;

/// Socket buffer size, each way: two full frames.
pub const SOCKET_BUF: usize = 2 * crate::modbus::frame::MAX_ADU;

/// An embassy-net stack serving Modbus/TCP on `port`, with the board's discovery effects.
pub struct EmbassyNet<E> {
    /// The stack.
    pub stack: Stack<'static>,
    /// The Modbus/TCP port.
    pub port: u16,
    /// The board's identify and restart.
    pub effects: E,
}

impl<E: Effects> Network for EmbassyNet<E> {
    async fn serve_modbus<M: RegisterMap>(
        &'static self,
        map: &'static Shared<M>,
        slots: &'static ModbusSlots,
        slot: usize,
    ) -> ! {
        let mut rx = [0u8; SOCKET_BUF];
        let mut tx = [0u8; SOCKET_BUF];
        loop {
            let mut socket = TcpSocket::new(self.stack, &mut rx, &mut tx);
            match accept(&mut socket, self.port, &MODBUS_BACKLOG).await {
                Ok(()) => {}
                Err(AcceptError::ConnectionReset) => {
                    debug!("modbus: slot {}: a handshake did not complete", slot);
                    reset(&mut socket).await;
                    continue;
                }
                Err(e) => {
                    warn!("modbus: accept failed: {:?}", e);
                    continue;
                }
            }
            debug!("modbus: slot {} connected", slot);
            let from = peer(&socket);
            let ended = serve_modbus(&mut socket, from, map, slots, slot).await;
            debug!("modbus: slot {} closed: {:?}", slot, ended);
            // Back to accepting at once, so that a newcomer finds a listening socket even in a
            // flood of connections: a peer that closed gets our FIN (every answer was flushed
            // already), briefly; an evicted, idle or broken connection is reset (the RST is
            // out within one pass of the network runner).
            if ended == Ended::PeerClosed {
                close(&mut socket).await;
            }
            reset(&mut socket).await;
        }
    }

    async fn serve_discovery<A: SettingsAccess, F: NorFlash>(
        &'static self,
        map: &'static Shared<A>,
        store: &'static Store<F, A::Settings>,
        identity: Identity,
    ) -> ! {
        let mut rx_meta = [PacketMetadata::EMPTY; 4];
        let mut tx_meta = [PacketMetadata::EMPTY; 4];
        let mut rx = [0u8; 4 * (MAX_DATAGRAM + 1)];
        let mut tx = [0u8; 4 * MAX_DATAGRAM];
        let mut socket = UdpSocket::new(self.stack, &mut rx_meta, &mut rx, &mut tx_meta, &mut tx);
        while socket.bind(PORT).is_err() {
            error!("discovery: cannot bind UDP port {}", PORT);
            Timer::after(Duration::from_secs(1)).await;
        }
        let mut datagrams = NetDatagrams(socket);
        serve(&mut datagrams, map, store, identity, async |effect| self.effects.apply(effect).await).await
    }

    async fn serve_update<A: SettingsAccess, F: NorFlash, U: UpdateTarget>(
        &'static self,
        map: &'static Shared<A>,
        store: &'static Store<F, A::Settings>,
        service: &mut UpdateService,
        target: &mut U,
    ) -> ! {
        // Bounded: one session at a time, through these buffers and the service's 1 KiB chunk.
        let mut rx = [0u8; 2048];
        let mut tx = [0u8; 64];
        loop {
            let mut socket = TcpSocket::new(self.stack, &mut rx, &mut tx);
            // The web console's steps are taken between two sessions.
            #[cfg(feature = "web")]
            let accepted = {
                let accepting = accept_one(&mut socket, crate::update::PORT, "update");
                match embassy_futures::select::select(accepting, crate::update::WEB.next()).await {
                    embassy_futures::select::Either::First(accepted) => accepted,
                    embassy_futures::select::Either::Second((number, step)) => {
                        let done = service.web_step(&step, map, store, target).await;
                        let updated = matches!(done, Ok(crate::update::WebDone::Updated(_)));
                        crate::update::WEB.answer(number, done);
                        // The console's connection restarts the module once it answered; if it
                        // cannot, this does, a little later.
                        if updated {
                            Timer::after(Duration::from_secs(3)).await;
                            self.restart().await;
                        }
                        continue;
                    }
                }
            };
            #[cfg(not(feature = "web"))]
            let accepted = accept_one(&mut socket, crate::update::PORT, "update").await;
            if !accepted {
                continue;
            }
            let now_ms = embassy_time::Instant::now().as_millis();
            let from = peer(&socket);
            let outcome = service.session(&mut socket, from, now_ms, map, store, target).await;
            close(&mut socket).await;
            reset(&mut socket).await;
            if let Outcome::Updated { .. } = outcome {
                self.restart().await;
            }
        }
    }

    /// Two tasks (issue #25: at most 2 connections, never a Modbus slot), each with its own
    /// socket and buffers; one request per connection, within the service's timeouts.
    #[cfg(feature = "web")]
    async fn serve_web<A: RegisterMap + SettingsAccess, F: NorFlash>(
        &'static self,
        map: &'static Shared<A>,
        store: &'static Store<F, A::Settings>,
        identity: Identity,
    ) -> ! {
        use crate::module::CommonSettings as _;
        use crate::web::service::{serve_connection, HTTP_BUFFER};
        // The stored port, in force from the start (a change takes effect at a restart).
        let port = store.lock().await.get().http_port();
        crate::web::settings::serving_on(port);
        let mut rx = [0u8; WEB_RX];
        let mut tx = [0u8; WEB_TX];
        let mut buffer = [0u8; HTTP_BUFFER];
        loop {
            let mut socket = TcpSocket::new(self.stack, &mut rx, &mut tx);
            // Through the web port's backlog: a browser's parallel connections wait for a task
            // instead of being reset.
            if let Err(e) = accept(&mut socket, port, &crate::backlog::WEB_BACKLOG).await {
                debug!("web: accept failed: {:?}", e);
                continue;
            }
            // A peer that stops acknowledging cannot hold the connection past this.
            socket.set_timeout(Some(WEB_IDLE));
            let from = peer(&socket);
            // picoserve closes the connection (or aborts it on an error or a timeout).
            let served = serve_connection(map, store, identity, from, socket, &mut buffer).await;
            if served.result.is_err() {
                debug!("web: a connection ended in an error or a timeout");
            }
            // A signed restart request was answered and its connection closed.
            if served.restart {
                self.restart().await;
            }
        }
    }

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

/// Accepts a connection on `port` through its backlog (`gate`: [`MODBUS_BACKLOG`], or the web
/// console's): the gate
/// learns the socket listens only once it does (the accept's first poll puts it in LISTEN),
/// and which client it took. A handshake that does not complete within
/// [`HANDSHAKE_TIMEOUT_MS`] (smoltcp would wait for ever: a SYN from a host gone, or spoofed)
/// ends it with `ConnectionReset`.
async fn accept(socket: &mut TcpSocket<'_>, port: u16, gate: &dyn Gate) -> Result<(), AcceptError> {
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
async fn accept_one(socket: &mut TcpSocket<'_>, port: u16, service: &str) -> bool {
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

/// The web console's socket buffers: a request larger than the receive buffer (up to the
/// service's 1.5 KiB) arrives in two windows, an answer of up to 2 KiB leaves in two.
#[cfg(feature = "web")]
const WEB_RX: usize = 1024;
#[cfg(feature = "web")]
const WEB_TX: usize = 1024;
/// A web connection whose peer stops acknowledging is dropped after this.
#[cfg(feature = "web")]
const WEB_IDLE: Duration = Duration::from_secs(10);

/// Sends our FIN after the last answer, waiting for it at most [`CLOSE_WAIT`].
async fn close(socket: &mut TcpSocket<'_>) {
    socket.close();
    let _ = with_timeout(CLOSE_WAIT, socket.flush()).await;
}

/// Resets the connection (nothing, if it is closed already), and waits, at most
/// [`CLOSE_WAIT`], for the RST to leave: a socket dropped at once leaves the stack before it
/// sends it, and its peer learns only from the RST answering its next request.
async fn reset(socket: &mut TcpSocket<'_>) {
    socket.abort();
    let _ = with_timeout(CLOSE_WAIT, socket.flush()).await;
}

/// The client: IPv4 address and port, if connected.
fn client(socket: &TcpSocket<'_>) -> Option<Peer> {
    match socket.remote_endpoint()? {
        IpEndpoint { addr: IpAddress::Ipv4(ip), port } => Some(Peer { ip: ip.octets(), port }),
    }
}

/// The client's IPv4 address (0.0.0.0 if unknown).
fn peer(socket: &TcpSocket<'_>) -> [u8; 4] {
    client(socket).map_or([0; 4], |client| client.ip)
}

/// How long a discovery reply may take to leave.
const SEND_WAIT: Duration = Duration::from_millis(500);

struct NetDatagrams<'a>(UdpSocket<'a>);

impl Datagrams for NetDatagrams<'_> {
    type Error = ();

    async fn recv(&mut self, buf: &mut [u8]) -> Result<(usize, [u8; 4], u16), ()> {
        let (n, meta) = self.0.recv_from(buf).await.map_err(|_| ())?;
        match meta.endpoint.addr {
            IpAddress::Ipv4(ip) => Ok((n, ip.octets(), meta.endpoint.port)),
        }
    }

    /// A reply to an address that never answers ARP (a forged source inside the subnet) stays
    /// at the head of smoltcp's queue for ever, and every later reply behind it: a reply not
    /// out within [`SEND_WAIT`] empties the queue (close, bind again), so one forged datagram
    /// cannot silence discovery.
    async fn send(&mut self, buf: &[u8], ip: [u8; 4], port: u16) -> Result<(), ()> {
        let sent = with_timeout(SEND_WAIT, async {
            self.0.send_to(buf, IpEndpoint::new(IpAddress::Ipv4(ip.into()), port)).await.map_err(|_| ())?;
            self.0.flush().await;
            Ok(())
        })
        .await;
        match sent {
            Ok(result) => result,
            Err(_) => {
                warn!("discovery: a reply could not leave (no ARP answer?): queue emptied");
                self.0.close();
                if self.0.bind(PORT).is_err() {
                    error!("discovery: cannot bind UDP port {} again", PORT);
                }
                Err(())
            }
        }
    }
}
