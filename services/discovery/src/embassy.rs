//! The discovery service on an embassy-net UDP socket (the STM32 and QEMU boards).

use embassy_net::udp::{PacketMetadata, UdpSocket};
use embassy_net::{IpAddress, IpEndpoint};
use embassy_time::{with_timeout, Duration, Timer};
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
    let mut tx_meta = [PacketMetadata::EMPTY; 4];
    let mut rx = [0u8; 4 * (MAX_DATAGRAM + 1)];
    let mut tx = [0u8; 4 * MAX_DATAGRAM];
    let mut socket = UdpSocket::new(net.stack, &mut rx_meta, &mut rx, &mut tx_meta, &mut tx);
    while socket.bind(PORT).is_err() {
        error!("discovery: cannot bind UDP port {}", PORT);
        Timer::after(Duration::from_secs(1)).await;
    }
    let mut datagrams = NetDatagrams(socket);
    serve_datagrams(&mut datagrams, map, store, identity, async |effect| net.effects.apply(effect).await).await
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
