//! The web console on embassy-net sockets (the STM32 and QEMU boards): each connection task
//! with its own socket and buffers, one request per connection, within the service's timeouts
//! (issue #25: at most 2 connections, never a Modbus slot).

use embassy_net::tcp::TcpSocket;
use embassy_time::Duration;
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_net::backlog::WEB_BACKLOG;
use remodaq_net::{accept, peer, EmbassyNet};
use remodaq_shared::board::{Effects, Network as _, Shared};
use remodaq_shared::debug;
use remodaq_shared::identity::Identity;
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::{CommonSettings as _, SettingsAccess, Store};

use crate::service::{serve_connection, HTTP_BUFFER};

/// The web console's socket buffers: a request larger than the receive buffer (up to the
/// service's 1.5 KiB) arrives in two windows, an answer of up to 1.75 KiB leaves in three (the
/// send buffer is smaller for the web part's RAM, issue #39; on a LAN each window is a fraction
/// of a millisecond).
const WEB_RX: usize = 1024;
const WEB_TX: usize = 768;
/// A web connection whose peer stops acknowledging is dropped after this.
const WEB_IDLE: Duration = Duration::from_secs(10);

/// Serves web console connections on `net`, one at a time, forever (each connection task runs
/// one).
pub async fn serve<E: Effects, A: RegisterMap + SettingsAccess, F: NorFlash>(
    net: &'static EmbassyNet<E>,
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    identity: Identity,
) -> ! {
    // The stored port, in force from the start (a change takes effect at a restart).
    let port = store.lock().await.get().http_port();
    crate::settings::serving_on(port);
    let mut rx = [0u8; WEB_RX];
    let mut tx = [0u8; WEB_TX];
    let mut buffer = [0u8; HTTP_BUFFER];
    loop {
        let mut socket = TcpSocket::new(net.stack, &mut rx, &mut tx);
        // Through the web port's backlog: a browser's parallel connections wait for a task
        // instead of being reset.
        if let Err(e) = accept(&mut socket, port, &WEB_BACKLOG).await {
            debug!("web: accept failed: {:?}", e);
            continue;
        }
        // A peer that stops acknowledging cannot hold the connection past this.
        socket.set_timeout(Some(WEB_IDLE));
        let from = peer(&socket);
        // picoserve closes the connection (or aborts it on an error or a timeout).
        // Made in place: awaited by value, its 5.7 KB would be copied through the task's poll
        // frame (issue #40: the stack).
        let served = core::pin::pin!(serve_connection(map, store, identity, from, socket, &mut buffer)).await;
        if served.result.is_err() {
            debug!("web: a connection ended in an error or a timeout");
        }
        // A signed restart request was answered and its connection closed.
        if served.restart {
            net.restart().await;
        }
    }
}
