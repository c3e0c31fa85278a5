//! MQTT's connection to the broker on embassy-net (the STM32 and QEMU boards): a TCP socket of
//! the stack's socket plan (`remodaq_net::STACK_SOCKETS` counts it, and SNTP's UDP socket, with
//! the feature `mqtt`), over buffers the service's task holds, and [`serve`], the service on it
//! beside the SNTP client.

use core::pin::pin;

use embassy_futures::select::{select, Either};
use embassy_net::tcp::TcpSocket;
use embassy_net::{IpEndpoint, Ipv4Address};
use embassy_time::Duration;
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_net::{close, reset, EmbassyNet};
use remodaq_shared::board::{Effects, Shared};
use remodaq_shared::identity::Identity;
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::{SettingsAccess, Store};
use remodaq_shared::warn;

use crate::service::{run, Board, Connector, KEEP_ALIVE_S};

/// The socket's buffers: what the module sends (publications of at most about 350 bytes) is
/// most; what it receives is acknowledgments and the odd command.
const SOCKET_RX: usize = 512;
const SOCKET_TX: usize = 768;

/// Opens connections to the broker on an embassy-net stack, one at a time through one socket,
/// which it keeps: the session's end (the settings changed) does not drop it unclosed, so the
/// broker learns at once that the module left and gives the will.
struct EmbassyConnector<'b> {
    socket: TcpSocket<'b>,
}

impl<'b> Connector for EmbassyConnector<'b> {
    type Io<'a>
        = &'a mut TcpSocket<'b>
    where
        Self: 'a;

    async fn connect(&mut self, broker: [u8; 4], port: u16) -> Option<&mut TcpSocket<'b>> {
        // The last connection, if the link broke without the socket knowing.
        reset(&mut self.socket).await;
        // A broker that stops acknowledging ends the connection (the session starts again):
        // twice the keep-alive, as the broker's own 1.5 and a margin.
        self.socket.set_timeout(Some(Duration::from_secs(2 * u64::from(KEEP_ALIVE_S))));
        let [a, b, c, d] = broker;
        match self.socket.connect(IpEndpoint::new(Ipv4Address::new(a, b, c, d).into(), port)).await {
            Ok(()) => Some(&mut self.socket),
            Err(e) => {
                warn!("mqtt: connect: {:?}", e);
                None
            }
        }
    }

    #[cfg(feature = "tls")]
    type Tls<'a>
        = crate::relay::Relay<'a, 'b>
    where
        Self: 'a;

    /// TLS by the worker off the main executor (`crate::relay`), which holds the record buffers:
    /// `buffer` is not used.
    #[cfg(feature = "tls")]
    async fn connect_tls<'a>(
        &'a mut self,
        broker: [u8; 4],
        port: u16,
        ca: &[u8],
        host: &str,
        _buffer: &'a mut [u8],
    ) -> Result<crate::relay::Relay<'a, 'b>, Option<crate::tls::Refused>> {
        // The last link's TLS first, before its socket is reset under it.
        crate::relay::stop().await;
        let socket = self.connect(broker, port).await.ok_or(None)?;
        crate::relay::open(socket, ca, host).await.map_err(Some)
    }

    async fn close(&mut self) {
        #[cfg(feature = "tls")]
        crate::relay::stop().await;
        close(&mut self.socket).await;
    }
}

/// Serves MQTT on `net` with the stored settings, forever, and keeps the module's time of day
/// from the time server they name (`crate::sntp`): the certificates' validity and the payloads'
/// `time` (`null` before the module has one).
pub async fn serve<E: Effects, A: RegisterMap + SettingsAccess, F: NorFlash>(
    net: &'static EmbassyNet<E>,
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    identity: Identity,
) -> ! {
    let (mut rx, mut tx) = ([0u8; SOCKET_RX], [0u8; SOCKET_TX]);
    let mut connector = EmbassyConnector { socket: TcpSocket::new(net.stack, &mut rx, &mut tx) };
    // TLS's record buffers are the worker's (`crate::relay`).
    let board = Board { time_ms: remodaq_shared::clock::now_ms, imposed: None, tls_buffer: &mut [] };
    // Made in place: passed by value, these futures would be copied through the stack first.
    let service = pin!(run(board, &mut connector, map, store, identity));
    let time = pin!(crate::sntp::keep_time(net));
    match select(service, time).await {
        Either::First(never) | Either::Second(never) => never,
    }
}
