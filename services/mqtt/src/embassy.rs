//! MQTT on embassy-net (the STM32 and QEMU boards), in two tasks (docs/mqtt.md, "Never in the
//! way"): [`serve`], the service, on the board's background executor, which every other task
//! preempts; [`link`], on the main executor, its TCP socket (`crate::link::carry`, of the stack's
//! socket plan: `remodaq_net::STACK_SOCKETS` counts it, and SNTP's UDP socket, with the feature
//! `mqtt`) beside the SNTP client.

use core::pin::pin;

use embassy_futures::select::{select, Either};
use embassy_net::tcp::TcpSocket;
use embassy_time::Duration;
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_net::EmbassyNet;
use remodaq_shared::board::Shared;
use remodaq_shared::identity::Identity;
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::{SettingsAccess, Store};

use crate::link::Link;
use crate::service::{run, Board, Connector, KEEP_ALIVE_S, TLS_BUFFER};

/// The socket's buffers: what the module sends (publications of at most about 350 bytes) is
/// most; what it receives is acknowledgments and the odd command.
const SOCKET_RX: usize = 512;
const SOCKET_TX: usize = 768;

/// Opens connections to the broker through the main executor's socket (`crate::link`), one at a
/// time (TLS, where asked, is the service's, over the link).
struct LinkConnector;

impl Connector for LinkConnector {
    type Io<'a> = Link;

    async fn connect(&mut self, broker: [u8; 4], port: u16) -> Option<Link> {
        crate::link::connect(broker, port).await
    }

    /// The session's end (the settings changed) does not leave the socket open: the broker
    /// learns at once that the module left, and gives the will.
    async fn close(&mut self) {
        crate::link::close().await;
    }
}

/// MQTT's socket on `net`, and the module's time of day from the time server the settings name
/// (`crate::sntp`: the certificates' validity and the payloads' `time`, `null` before the module
/// has one), for ever: run it on the main executor.
pub async fn link<E>(net: &'static EmbassyNet<E>) -> ! {
    let (mut rx, mut tx) = ([0u8; SOCKET_RX], [0u8; SOCKET_TX]);
    let mut socket = TcpSocket::new(net.stack, &mut rx, &mut tx);
    // A broker that stops acknowledging ends the connection (the session starts again): twice
    // the keep-alive, as the broker's own 1.5 and a margin.
    let carried = pin!(crate::link::carry(&mut socket, Duration::from_secs(2 * u64::from(KEEP_ALIVE_S))));
    let time = pin!(crate::sntp::keep_time(net));
    match select(carried, time).await {
        Either::First(never) | Either::Second(never) => never,
    }
}

/// Serves MQTT with the stored settings, for ever, through [`link`]'s socket: run it on the
/// board's background executor (its future holds TLS's record buffers: pin it where it is made).
pub async fn serve<A: RegisterMap + SettingsAccess, F: NorFlash>(
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    identity: Identity,
) -> ! {
    let mut tls_buffer = [0u8; TLS_BUFFER];
    let board = Board { time_ms: remodaq_shared::clock::now_ms, imposed: None, tls_buffer: &mut tls_buffer };
    run(board, &mut LinkConnector, map, store, identity).await
}
