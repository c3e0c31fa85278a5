//! The Modbus/TCP listener on embassy-net: each connection task owns one TCP socket, accepts
//! on the module's port and runs the shared connection server on it.

use embassy_net::tcp::TcpSocket;
use embassy_net::Stack;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::{with_timeout, Duration};
use remodaq_shared::modbus::server::{serve, Slots, SOCKETS};
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::{debug, warn};

/// The connection slots of a module.
pub type ModbusSlots = Slots<CriticalSectionRawMutex, SOCKETS>;
/// Socket buffer size, each way: two full frames.
pub const SOCKET_BUF: usize = 2 * remodaq_shared::modbus::frame::MAX_ADU;

/// Connection task `slot`: accept on `port`, serve until the connection ends, repeat.
pub async fn connection_task<M: RegisterMap>(
    stack: Stack<'static>,
    port: u16,
    map: &Mutex<CriticalSectionRawMutex, M>,
    slots: &ModbusSlots,
    slot: usize,
) -> ! {
    let mut rx = [0u8; SOCKET_BUF];
    let mut tx = [0u8; SOCKET_BUF];
    loop {
        let mut socket = TcpSocket::new(stack, &mut rx, &mut tx);
        if let Err(e) = socket.accept(port).await {
            warn!("modbus: accept failed: {:?}", e);
            continue;
        }
        debug!("modbus: slot {} connected", slot);
        let ended = serve(&mut socket, map, slots, slot).await;
        debug!("modbus: slot {} closed: {:?}", slot, ended);
        socket.close();
        let _ = with_timeout(Duration::from_secs(2), socket.flush()).await;
        socket.abort();
        let _ = with_timeout(Duration::from_secs(1), socket.flush()).await;
    }
}
