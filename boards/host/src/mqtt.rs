//! MQTT on the simulated module (docs/mqtt.md): the service of `remodaq_mqtt` over std TCP
//! connections, with MQTT's stored settings (over TLS with the stored CA certificate and
//! credentials, the PC's clock as the module's time); or, with the simulator's `--mqtt
//! ADDR:PORT`, to that broker whatever is stored (plain and anonymous, the default prefix, a 1 s
//! period, QoS 1, the 8350's points on change and its commands on), as `--listen` and `--http`
//! override the stored ports.

use std::net::{SocketAddr, SocketAddrV4, TcpStream};

use async_io::Async;
use embedded_io_adapters::futures_03::FromFutures;
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_mqtt::service::{self, Board, Connector};
use remodaq_shared::board::Shared;
use remodaq_shared::identity::Identity;
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::{SettingsAccess, Store};
use remodaq_shared::mqtt::Config;
use remodaq_shared::settings::Schema as _;

/// What `--mqtt ADDR:PORT` stands for: on, plain, that broker, the rest as documented above.
fn overridden(broker: SocketAddr) -> Config {
    let ip = match broker.ip() {
        std::net::IpAddr::V4(ip) => ip.octets(),
        std::net::IpAddr::V6(_) => [0; 4],
    };
    Config {
        on: true,
        broker: ip,
        port: broker.port(),
        tls: false,
        period_ms: 1_000,
        at_least_once: true,
        on_change: true,
        commands: true,
        ..Config::defaults()
    }
}

/// Opens the broker's connections with std sockets.
struct StdConnector;

impl Connector for StdConnector {
    type Io<'a> = FromFutures<Async<TcpStream>>;

    async fn connect(&mut self, broker: [u8; 4], port: u16) -> Option<Self::Io<'_>> {
        let broker = SocketAddr::V4(SocketAddrV4::new(broker.into(), port));
        match Async::<TcpStream>::connect(broker).await {
            Ok(stream) => Some(FromFutures::new(stream)),
            Err(e) => {
                log::warn!("mqtt: {broker}: {e}");
                None
            }
        }
    }
}

/// The time of day from the PC's clock.
fn time_ms() -> Option<u64> {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).ok().map(|d| d.as_millis() as u64)
}

/// Serves MQTT for ever: with `broker` (`--mqtt`) when given, else with the stored settings.
pub async fn run<A: RegisterMap + SettingsAccess, F: NorFlash>(
    broker: Option<SocketAddr>,
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    identity: Identity,
) -> ! {
    let mut tls_buffer = vec![0u8; service::TLS_BUFFER];
    let board = Board { time_ms, imposed: broker.map(overridden), tls_buffer: &mut tls_buffer };
    service::run(board, &mut StdConnector, map, store, identity).await
}
