//! MQTT on the simulated module (`--mqtt ADDR:PORT`, docs/mqtt.md): the session of
//! `remodaq_mqtt` over a std TCP connection to a broker, plain and anonymous, with the default
//! prefix (`remodaq/<model>/<mac>`), a 1 s period, QoS 1, the 8350's points on change and its
//! commands on. A stand-in for the module's stored MQTT settings, which are not built yet: the
//! simulator's flag, as `--listen` and `--http` are. Reconnects after 1 s, doubling to 30 s.

use std::net::{SocketAddr, TcpStream};

use async_io::Async;
use embassy_time::{Duration, Instant, Timer};
use embedded_io_adapters::futures_03::FromFutures;
use minimq::{Buffers, ConfigBuilder, QoS, Session, Will};
use remodaq_mqtt::points::{MapModule, Options};
use remodaq_mqtt::schedule::Point;
use remodaq_mqtt::session::{serve, Settings, OFFLINE};
use remodaq_mqtt::topics;
use remodaq_shared::board::Shared;
use remodaq_shared::identity::Identity;
use remodaq_shared::modbus::RegisterMap;

/// The longest wait between two attempts.
const BACK_OFF_MAX: Duration = Duration::from_secs(30);

/// Serves MQTT to `broker` for ever.
pub async fn run<A: RegisterMap>(broker: SocketAddr, map: &'static Shared<A>, identity: Identity) -> ! {
    let prefix = topics::default_prefix(identity.model, identity.mac);
    let status = topics::leaf(&prefix, "status");
    let mut digits = [0u8; 12];
    let client_id = format!("remodaq-{}", remodaq_protocol::web::hex(&identity.mac, &mut digits).unwrap_or(""));
    let (mut rx, mut tx) = ([0u8; 1024], [0u8; 4096]);
    let will = Will::new(&status, OFFLINE.as_bytes(), &[]).map(|w| w.retained().qos(QoS::AtLeastOnce));
    let config = ConfigBuilder::new(Buffers::new(&mut rx, &mut tx))
        .client_id(&client_id)
        .map(|c| c.keepalive_interval(10).session_expiry_interval(300));
    let Some(config) = config.ok().and_then(|c| will.ok().and_then(|w| c.will(w).ok())) else {
        log::error!("mqtt: the session's configuration was refused");
        loop {
            core::future::pending::<()>().await;
        }
    };
    let mut session = Session::new(config);
    let settings = Settings { prefix: &prefix, period_ms: 1_000, at_least_once: true, commands: true };
    let broker_ip = match broker.ip() {
        std::net::IpAddr::V4(ip) => ip.octets(),
        std::net::IpAddr::V6(_) => [0; 4],
    };
    let options = Options { deadbands: [0; 8], on_change: true, broker: broker_ip };
    let mut module = MapModule {
        map,
        model: identity.model,
        firmware: identity.version,
        mac: identity.mac,
        uptime_s: || Instant::now().as_secs(),
        time_ms: || {
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).ok().map(|d| d.as_millis() as u64)
        },
        options,
        refusals: [0; 3],
    };
    // A schedule per point: the most a module has (the 8350's 12 DIs and 6 DOs).
    let mut schedules = [Point::new(); 18];
    let mut back_off = Duration::from_secs(1);
    log::info!("mqtt: publishing to {broker} under {prefix}");
    loop {
        match Async::<TcpStream>::connect(broker).await {
            Ok(stream) => {
                let ended = serve(&mut session, FromFutures::new(stream), &settings, &mut module, &mut schedules).await;
                log::warn!("mqtt: the connection to {broker} ended ({ended:?})");
                back_off = Duration::from_secs(1);
            }
            Err(e) => log::warn!("mqtt: {broker}: {e}"),
        }
        Timer::after(back_off).await;
        back_off = (back_off * 2).min(BACK_OFF_MAX);
    }
}
