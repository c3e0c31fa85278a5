//! The Modbus/TCP listener of the simulated module: each connection task accepts on the shared
//! std listener and runs the shared connection server on the socket.

use std::net::{TcpListener, TcpStream};

use async_io::Async;
use embedded_io_adapters::futures_03::FromFutures;
use remodaq_modbus::server::serve;
use remodaq_modbus::ModbusSlots;
use remodaq_shared::board::Shared;
use remodaq_shared::modbus::RegisterMap;

/// The Modbus/TCP listener.
pub type Listener = Async<TcpListener>;

/// Binds the Modbus/TCP listener.
pub fn bind(addr: std::net::SocketAddr) -> std::io::Result<Listener> {
    Async::<TcpListener>::bind(addr)
}

/// Connection task `slot`: accept, serve until the connection ends, repeat.
pub async fn connection_task<M: RegisterMap>(
    listener: &Listener,
    map: &Shared<M>,
    slots: &ModbusSlots,
    slot: usize,
) -> ! {
    loop {
        let (stream, peer) = accept(listener, "modbus").await;
        log::debug!("modbus: slot {slot} serves {peer}");
        let mut io = FromFutures::new(stream);
        let ended = serve(&mut io, ipv4(peer.ip()), map, slots, slot).await;
        log::debug!("modbus: slot {slot} closed {peer}: {ended:?}");
        let stream: Async<TcpStream> = io.into_inner();
        let _ = stream.get_ref().shutdown(std::net::Shutdown::Both);
    }
}

/// The next connection on `listener` (of the service `what`, for the log), with Nagle's delay
/// off; a failed accept is logged and tried again 100 ms later.
pub async fn accept(listener: &Async<TcpListener>, what: &str) -> (Async<TcpStream>, std::net::SocketAddr) {
    loop {
        match listener.accept().await {
            Ok((stream, peer)) => {
                let _ = stream.get_ref().set_nodelay(true);
                return (stream, peer);
            }
            Err(e) => {
                log::warn!("{what}: accept failed: {e}");
                async_io::Timer::after(std::time::Duration::from_millis(100)).await;
            }
        }
    }
}

/// A client's IPv4 address for the access rule (an IPv4-mapped IPv6 address is unmapped;
/// another IPv6 address is unknown: 0.0.0.0, which only an empty allow-list lets write).
pub fn ipv4(ip: std::net::IpAddr) -> [u8; 4] {
    match ip {
        std::net::IpAddr::V4(v4) => v4.octets(),
        std::net::IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or([0; 4], |v4| v4.octets()),
    }
}
