//! The discovery service on an embassy-net UDP socket (the STM32 and QEMU boards).

use embassy_net::udp::{PacketMetadata, UdpSocket};
use embassy_net::{IpAddress, IpEndpoint};
use embassy_time::{Duration, Instant, Timer};
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_net::EmbassyNet;
use remodaq_shared::board::{Effects, Shared};
use remodaq_shared::module::{SettingsAccess, Store};
use remodaq_shared::{error, warn};

use crate::{serve as serve_datagrams, Datagrams, Identity, MAX_DATAGRAM, PORT};

/// Serves the discovery and configuration protocol on `net`, forever, with the board's identify
/// and restart.
pub async fn serve<E: Effects, A: SettingsAccess, F: NorFlash>(
    net: &'static EmbassyNet<E>,
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    identity: Identity,
) -> ! {
    let mut rx_meta = [PacketMetadata::EMPTY; 4];
    let mut rx = [0u8; 4 * (MAX_DATAGRAM + 1)];
    let mut sending = [const { Sending { meta: [PacketMetadata::EMPTY], buf: [0; MAX_DATAGRAM] } }; SENDERS];
    // The receiving socket first, the senders right after it with no await between: smoltcp
    // hands a datagram to the first socket bound to its port in the stack's socket set, which
    // is in slot order, and a new socket takes the lowest free slot. The receiver took the
    // lowest, so every sender's slot is above it and requests always reach the receiver.
    let receiver = UdpSocket::new(net.stack, &mut rx_meta, &mut rx, &mut [], &mut []);
    let mut senders = sending.each_mut().map(|s| UdpSocket::new(net.stack, &mut [], &mut [], &mut s.meta, &mut s.buf));
    let mut receiver = receiver;
    for socket in core::iter::once(&mut receiver).chain(senders.iter_mut()) {
        while socket.bind(PORT).is_err() {
            error!("discovery: cannot bind UDP port {}", PORT);
            Timer::after(Duration::from_secs(1)).await;
        }
    }
    let mut datagrams = NetDatagrams { receiver, senders, since: [Instant::MIN; SENDERS] };
    serve_datagrams(&mut datagrams, map, store, identity, async |effect| net.effects.apply(effect).await).await
}

/// How long a discovery reply may take to leave before its sender is wanted for another.
const SEND_WAIT: Duration = Duration::from_millis(500);
/// Sockets replies leave through, one reply each.
const SENDERS: usize = remodaq_shared::sockets::DISCOVERY_SENDERS;

/// A sender's buffers: one reply.
struct Sending {
    meta: [PacketMetadata; 1],
    buf: [u8; MAX_DATAGRAM],
}

/// Requests arrive on `receiver`, which is never emptied; each reply leaves through a sender of
/// its own. A reply to an address that never answers ARP (a forged source inside the subnet)
/// stays queued in its sender for ever (security review finding 5): it holds that sender only,
/// and once every sender is taken, the one whose reply has waited longest (at least
/// [`SEND_WAIT`]) is emptied for the next reply. So a trickle of forged requests neither
/// blocks the service nor throws away the requests queued behind them.
struct NetDatagrams<'a> {
    receiver: UdpSocket<'a>,
    senders: [UdpSocket<'a>; SENDERS],
    /// When each sender took its reply.
    since: [Instant; SENDERS],
}

impl NetDatagrams<'_> {
    /// A sender free for a reply: one whose reply left, or else the one whose reply has waited
    /// longest, emptied once it has waited [`SEND_WAIT`].
    async fn sender(&mut self) -> usize {
        loop {
            if let Some(free) = self.senders.iter().position(|s| s.may_send()) {
                return free;
            }
            let (oldest, since) =
                self.since.iter().copied().enumerate().min_by_key(|(_, since)| *since).unwrap_or((0, Instant::MIN));
            if Instant::now() >= since + SEND_WAIT {
                warn!("discovery: a reply could not leave (no ARP answer?): dropped");
                let socket = &mut self.senders[oldest];
                socket.close();
                if socket.bind(PORT).is_err() {
                    error!("discovery: cannot bind UDP port {} again", PORT);
                }
                return oldest;
            }
            Timer::after(Duration::from_millis(5)).await;
        }
    }
}

impl Datagrams for NetDatagrams<'_> {
    type Error = ();

    async fn recv(&mut self, buf: &mut [u8]) -> Result<(usize, [u8; 4], u16), ()> {
        let (n, meta) = self.receiver.recv_from(buf).await.map_err(|_| ())?;
        match meta.endpoint.addr {
            IpAddress::Ipv4(ip) => Ok((n, ip.octets(), meta.endpoint.port)),
        }
    }

    /// Queues the reply in a free sender and returns: it leaves once the destination's link
    /// address is known.
    async fn send(&mut self, buf: &[u8], ip: [u8; 4], port: u16) -> Result<(), ()> {
        let i = self.sender().await;
        self.senders[i].send_to(buf, IpEndpoint::new(IpAddress::Ipv4(ip.into()), port)).await.map_err(|_| ())?;
        self.since[i] = Instant::now();
        Ok(())
    }
}
