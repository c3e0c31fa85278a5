//! The network services on embassy-net sockets, for every board that runs embassy-net (the
//! STM32 and QEMU boards): the Modbus/TCP connection tasks and the discovery socket.

use embassy_net::tcp::TcpSocket;
use embassy_net::udp::{PacketMetadata, UdpSocket};
use embassy_net::{IpAddress, IpEndpoint, Stack};
use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, RawMutex};
use embassy_sync::mutex::Mutex;
use embassy_time::{with_timeout, Duration, Timer};

use crate::discovery::{serve, Datagrams, Effect, Identity, MAX_DATAGRAM, PORT};
use crate::modbus::server::{serve as serve_modbus, Slots, SOCKETS};
use crate::modbus::RegisterMap;
use crate::module::SettingsAccess;
use crate::{debug, error, warn};

/// Spawns a task, logging (instead of panicking) if its pool is exhausted.
pub fn spawn<S>(
    spawner: &embassy_executor::Spawner,
    token: Result<embassy_executor::SpawnToken<S>, embassy_executor::SpawnError>,
    name: &str,
) {
    match token {
        Ok(token) => spawner.spawn(token),
        Err(_) => error!("cannot start task {}", name),
    }
}

/// The connection slots of a module.
pub type ModbusSlots = Slots<CriticalSectionRawMutex, SOCKETS>;
/// Socket buffer size, each way: two full frames.
pub const SOCKET_BUF: usize = 2 * crate::modbus::frame::MAX_ADU;

/// Modbus connection task `slot`: accept on `port`, serve until the connection ends, repeat.
pub async fn modbus_connection<M: RegisterMap>(
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
        let ended = serve_modbus(&mut socket, map, slots, slot).await;
        debug!("modbus: slot {} closed: {:?}", slot, ended);
        socket.close();
        let _ = with_timeout(Duration::from_secs(2), socket.flush()).await;
        socket.abort();
        let _ = with_timeout(Duration::from_secs(1), socket.flush()).await;
    }
}

struct NetDatagrams<'a>(UdpSocket<'a>);

impl Datagrams for NetDatagrams<'_> {
    type Error = ();

    async fn recv(&mut self, buf: &mut [u8]) -> Result<(usize, [u8; 4], u16), ()> {
        let (n, meta) = self.0.recv_from(buf).await.map_err(|_| ())?;
        match meta.endpoint.addr {
            IpAddress::Ipv4(ip) => Ok((n, ip.octets(), meta.endpoint.port)),
        }
    }

    async fn send(&mut self, buf: &[u8], ip: [u8; 4], port: u16) -> Result<(), ()> {
        self.0.send_to(buf, IpEndpoint::new(IpAddress::Ipv4(ip.into()), port)).await.map_err(|_| ())
    }
}

/// Serves the discovery protocol forever on UDP [`PORT`]; `effect` carries out identify and
/// restart the board's way.
pub async fn discovery<R: RawMutex, A: SettingsAccess>(
    stack: Stack<'static>,
    map: &Mutex<R, A>,
    identity: Identity,
    effect: impl AsyncFnMut(Effect),
) -> ! {
    let mut rx_meta = [PacketMetadata::EMPTY; 4];
    let mut tx_meta = [PacketMetadata::EMPTY; 4];
    let mut rx = [0u8; 4 * (MAX_DATAGRAM + 1)];
    let mut tx = [0u8; 4 * MAX_DATAGRAM];
    let mut socket = UdpSocket::new(stack, &mut rx_meta, &mut rx, &mut tx_meta, &mut tx);
    while socket.bind(PORT).is_err() {
        error!("discovery: cannot bind UDP port {}", PORT);
        Timer::after(Duration::from_secs(1)).await;
    }
    let mut datagrams = NetDatagrams(socket);
    serve(&mut datagrams, map, identity, effect).await
}

/// Declares a firmware's network tasks on an embassy-net board, for the register map type
/// `$map` (behind a `Mutex<CriticalSectionRawMutex, _>`) and the board's discovery function
/// `$discovery(stack, map, identity)`: `modbus_task` (one per connection slot),
/// `discovery_task`, and `spawn_network(spawner, stack, port, map, identity)` that starts them.
/// (Embassy tasks cannot be generic, so each firmware declares concrete ones.)
#[macro_export]
macro_rules! embassy_net_tasks {
    ($map:ty, $discovery:path) => {
        static SLOTS: $crate::embassy_net::ModbusSlots =
            $crate::modbus::server::Slots::new($crate::modbus::server::MAX_CONNECTIONS);

        #[embassy_executor::task(pool_size = $crate::modbus::server::SOCKETS)]
        async fn modbus_task(stack: embassy_net::Stack<'static>, port: u16, map: &'static $map, slot: usize) -> ! {
            $crate::embassy_net::modbus_connection(stack, port, map, &SLOTS, slot).await
        }

        #[embassy_executor::task]
        async fn discovery_task(
            stack: embassy_net::Stack<'static>,
            map: &'static $map,
            identity: $crate::discovery::Identity,
        ) -> ! {
            $discovery(stack, map, identity).await
        }

        /// Starts the Modbus/TCP connection tasks and the discovery service.
        fn spawn_network(
            spawner: &embassy_executor::Spawner,
            stack: embassy_net::Stack<'static>,
            port: u16,
            map: &'static $map,
            identity: $crate::discovery::Identity,
        ) {
            for slot in 0..$crate::modbus::server::SOCKETS {
                $crate::embassy_net::spawn(spawner, modbus_task(stack, port, map, slot), "modbus");
            }
            $crate::embassy_net::spawn(spawner, discovery_task(stack, map, identity), "discovery");
        }
    };
}
