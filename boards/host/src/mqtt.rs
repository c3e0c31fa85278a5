//! MQTT on the simulated module (docs/mqtt.md): the session of `remodaq_mqtt` over a std TCP
//! connection to a broker, with MQTT's stored settings (`settings::key::MQTT`, set through the
//! web console's `PUT /api/v1/mqtt`), started again whenever they change; or, with the
//! simulator's `--mqtt ADDR:PORT`, to that broker whatever is stored (plain and anonymous, the
//! default prefix, a 1 s period, QoS 1, the 8350's points on change and its commands on), as
//! `--listen` and `--http` override the stored ports. TLS needs the CA certificate, which is
//! not stored yet: settings with TLS on connect nowhere, and say so. Reconnects after 1 s,
//! doubling to 30 s.

use std::net::{SocketAddr, SocketAddrV4, TcpStream};

use async_io::Async;
use embassy_futures::select::{select, Either};
use embassy_time::{Duration, Instant, Timer};
use embedded_io_adapters::futures_03::FromFutures;
use embedded_storage_async::nor_flash::NorFlash;
use minimq::{Buffers, ConfigBuilder, QoS, Session, Will};
use remodaq_mqtt::points::{MapModule, Options};
use remodaq_mqtt::schedule::Point;
use remodaq_mqtt::session::{serve, Settings, OFFLINE};
use remodaq_mqtt::topics;
use remodaq_shared::board::Shared;
use remodaq_shared::identity::Identity;
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::{SettingsAccess, Store};
use remodaq_shared::mqtt::{Config, CHANGED};
use remodaq_shared::settings::{key, Schema as _};

/// The longest wait between two attempts.
const BACK_OFF_MAX: Duration = Duration::from_secs(30);

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

/// Serves MQTT for ever: with `broker` (`--mqtt`) when given, else with the stored settings,
/// each session until they change.
pub async fn run<A: RegisterMap + SettingsAccess, F: NorFlash>(
    broker: Option<SocketAddr>,
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    identity: Identity,
) -> ! {
    loop {
        let config = match broker {
            Some(broker) => overridden(broker),
            None => store.lock().await.service_record::<Config>(key::MQTT).await,
        };
        if !config.on {
            log::info!("mqtt: off");
        } else if config.tls {
            log::warn!(
                "mqtt: TLS needs the broker's CA certificate, which this simulator cannot store yet: not connected"
            );
        } else {
            match select(session(&config, map, identity), CHANGED.wait()).await {
                Either::First(never) => match never {},
                Either::Second(()) => log::info!("mqtt: the settings changed: starting again"),
            }
            continue;
        }
        CHANGED.wait().await;
    }
}

/// One configuration's sessions, reconnecting for ever.
async fn session<A: RegisterMap>(
    config: &Config,
    map: &'static Shared<A>,
    identity: Identity,
) -> core::convert::Infallible {
    let prefix = if config.prefix.is_empty() {
        topics::default_prefix(identity.model, identity.mac)
    } else {
        config.prefix.clone()
    };
    let status = topics::leaf(&prefix, "status");
    let mut digits = [0u8; 12];
    let client_id = if config.client_id.is_empty() {
        format!("remodaq-{}", remodaq_protocol::web::hex(&identity.mac, &mut digits).unwrap_or(""))
    } else {
        config.client_id.to_string()
    };
    let (mut rx, mut tx) = ([0u8; 1024], [0u8; 4096]);
    let qos = if config.at_least_once { QoS::AtLeastOnce } else { QoS::AtMostOnce };
    let will = Will::new(&status, OFFLINE.as_bytes(), &[]).map(|w| w.retained().qos(qos));
    let built = ConfigBuilder::new(Buffers::new(&mut rx, &mut tx))
        .client_id(&client_id)
        .map(|c| c.keepalive_interval(10).session_expiry_interval(300));
    let Some(built) = built.ok().and_then(|c| will.ok().and_then(|w| c.will(w).ok())) else {
        log::error!("mqtt: the session's configuration was refused");
        return core::future::pending().await;
    };
    let mut session = Session::new(built);
    let settings = Settings {
        prefix: &prefix,
        period_ms: config.period_ms,
        at_least_once: config.at_least_once,
        commands: config.commands,
    };
    let options = Options { deadbands: config.deadbands, on_change: config.on_change, broker: config.broker };
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
    let broker = SocketAddr::V4(SocketAddrV4::new(config.broker.into(), config.port));
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
