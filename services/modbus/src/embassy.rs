//! The Modbus/TCP service on embassy-net sockets (the STM32 and QEMU boards): one connection
//! task per slot, each accepting through the port's SYN backlog (`remodaq_net::backlog`).

use embassy_net::tcp::{AcceptError, TcpSocket};
use remodaq_net::backlog::MODBUS_BACKLOG;
use remodaq_net::{accept, close, peer, reset, EmbassyNet};
use remodaq_shared::board::{Effects, Shared};
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::{debug, warn};

use crate::frame::MAX_ADU;
use crate::server::{serve as serve_connection, Ended};
use crate::ModbusSlots;

/// Socket buffer size, each way: two full frames.
pub const SOCKET_BUF: usize = 2 * MAX_ADU;

/// Accepts and serves Modbus/TCP connections in `slot` on `net`'s Modbus port, forever.
pub async fn serve<E: Effects, M: RegisterMap>(
    net: &'static EmbassyNet<E>,
    map: &'static Shared<M>,
    slots: &'static ModbusSlots,
    slot: usize,
) -> ! {
    let mut rx = [0u8; SOCKET_BUF];
    let mut tx = [0u8; SOCKET_BUF];
    loop {
        let mut socket = TcpSocket::new(net.stack, &mut rx, &mut tx);
        match accept(&mut socket, net.port, &MODBUS_BACKLOG).await {
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
        let ended = serve_connection(&mut socket, from, map, slots, slot).await;
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
