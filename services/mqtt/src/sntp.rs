//! The time of day on the embassy-net boards (docs/mqtt.md, "Time"): SNTP (RFC 4330, `sntpc`)
//! from the time server MQTT's settings name (`Config::sntp`, which the MQTT service hands to
//! `remodaq_shared::clock::set_server`), into the module's clock (`remodaq_shared::clock`):
//! every 10 s until the first answer, then every hour, and at once when the server changes. TLS checks a
//! certificate's validity against it, and the payloads' `time` is it; without one, neither is
//! there (no TLS connection is tried: `tls::Refused::NoTime`).

use core::net::{IpAddr, SocketAddr};

use embassy_futures::select::{select, Either};
use embassy_net::udp::{PacketMetadata, UdpSocket};
use embassy_net::{IpAddress, IpEndpoint};
use embassy_time::{Duration, Instant, Timer};
use remodaq_net::EmbassyNet;
use remodaq_shared::{clock, debug, info};
use sntpc::{NtpContext, NtpTimestampGenerator, NtpUdpSocket};

/// How long an answer is waited for.
const ANSWER: Duration = Duration::from_secs(2);
/// Asked again this often until a first answer.
const RETRY: Duration = Duration::from_secs(10);
/// Asked again this often once the module has a time.
const REFRESH: Duration = Duration::from_secs(3600);

/// The module's clock as SNTP's timestamps: the time of day if the module has one, else its
/// uptime (the request's own timestamp only matches the answer to the request).
#[derive(Clone, Copy, Default)]
struct Stamps(u64);

impl NtpTimestampGenerator for Stamps {
    fn init(&mut self) {
        self.0 = clock::now_ms().unwrap_or_else(|| Instant::now().as_millis()) * 1000;
    }
    fn timestamp_sec(&self) -> u64 {
        self.0 / 1_000_000
    }
    fn timestamp_subsec_micros(&self) -> u32 {
        (self.0 % 1_000_000) as u32
    }
}

/// An embassy-net UDP socket as `sntpc`'s.
struct Socket<'a>(UdpSocket<'a>);

impl NtpUdpSocket for Socket<'_> {
    async fn send_to(&self, buf: &[u8], addr: SocketAddr) -> sntpc::Result<usize> {
        let IpAddr::V4(ip) = addr.ip() else { return Err(sntpc::Error::Network) };
        let to = IpEndpoint::new(IpAddress::Ipv4(ip), addr.port());
        self.0.send_to(buf, to).await.map(|()| buf.len()).map_err(|_| sntpc::Error::Network)
    }
    async fn recv_from(&self, buf: &mut [u8]) -> sntpc::Result<(usize, SocketAddr)> {
        let (n, meta) = self.0.recv_from(buf).await.map_err(|_| sntpc::Error::Network)?;
        let IpAddress::Ipv4(ip) = meta.endpoint.addr;
        Ok((n, SocketAddr::new(IpAddr::V4(ip), meta.endpoint.port)))
    }
}

/// Keeps the module's clock from the time server named (`clock::server`), forever; asks the
/// new one at once when it changes.
pub async fn keep_time<E>(net: &'static EmbassyNet<E>) -> ! {
    let (mut rx_meta, mut tx_meta) = ([PacketMetadata::EMPTY; 1], [PacketMetadata::EMPTY; 1]);
    let (mut rx, mut tx) = ([0u8; 64], [0u8; 64]);
    let mut socket = UdpSocket::new(net.stack, &mut rx_meta, &mut rx, &mut tx_meta, &mut tx);
    // Any local port: the answer comes back to it.
    while socket.bind(0).is_err() {
        Timer::after(RETRY).await;
    }
    let socket = Socket(socket);
    loop {
        let mut wait = RETRY;
        if let Some((ip, port)) = clock::server() {
            let to = SocketAddr::new(IpAddr::V4(ip.into()), port);
            let asked = sntpc::get_time(to, &socket, NtpContext::new(Stamps::default()));
            match select(asked, Timer::after(ANSWER)).await {
                Either::First(Ok(answer)) => {
                    let ms =
                        answer.seconds * 1000 + u64::from(sntpc::fraction_to_milliseconds(answer.seconds_fraction));
                    if clock::now_ms().is_none() {
                        info!("sntp: the time of day is known ({} s since 1970)", answer.seconds);
                    }
                    clock::set(ms);
                    wait = REFRESH;
                }
                Either::First(Err(_)) => debug!("sntp: no usable answer"),
                Either::Second(()) => debug!("sntp: no answer within 2 s"),
            }
        }
        let _ = select(Timer::after(wait), clock::SERVER_CHANGED.wait()).await;
    }
}
