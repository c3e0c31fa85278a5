//! The discovery / configuration service on embassy-net UDP. Identify blinks LD1 for 10 s;
//! restart resets the MCU once the reply has had time to leave.

use embassy_net::udp::{PacketMetadata, UdpSocket};
use embassy_net::{IpAddress, IpEndpoint, Stack};
use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, RawMutex};
use embassy_sync::mutex::Mutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Timer};
use remodaq_shared::discovery::{serve, Datagrams, Effect, Identity, MAX_DATAGRAM, PORT};
use remodaq_shared::module::SettingsAccess;

/// Raised to blink the identify LED.
pub static IDENTIFY: Signal<CriticalSectionRawMutex, ()> = Signal::new();

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

/// Serves the protocol forever on [`PORT`].
pub async fn run<R: RawMutex, A: SettingsAccess>(stack: Stack<'static>, map: &Mutex<R, A>, identity: Identity) -> ! {
    let mut rx_meta = [PacketMetadata::EMPTY; 4];
    let mut tx_meta = [PacketMetadata::EMPTY; 4];
    let mut rx = [0u8; 4 * (MAX_DATAGRAM + 1)];
    let mut tx = [0u8; 4 * MAX_DATAGRAM];
    let mut socket = UdpSocket::new(stack, &mut rx_meta, &mut rx, &mut tx_meta, &mut tx);
    while socket.bind(PORT).is_err() {
        remodaq_shared::error!("discovery: cannot bind UDP port {}", PORT);
        Timer::after(Duration::from_secs(1)).await;
    }
    let mut datagrams = NetDatagrams(socket);
    serve(&mut datagrams, map, identity, async |effect| match effect {
        Effect::None => {}
        Effect::Identify => IDENTIFY.signal(()),
        Effect::Restart => {
            remodaq_shared::info!("restart requested");
            Timer::after(Duration::from_millis(300)).await;
            cortex_m::peripheral::SCB::sys_reset();
        }
    })
    .await
}
