//! MQTT's service on every board (docs/mqtt.md): with the stored settings (`settings::key::MQTT`,
//! set through the web console's `PUT /api/v1/mqtt` and `remodaq mqtt set`), or with settings a
//! board imposes (the simulator's `--mqtt ADDR:PORT`), the [`session`](crate::session) over a
//! connection the board opens ([`Connector`]: std sockets on the host, an embassy-net socket on
//! the STM32 and QEMU boards), reconnecting after 1 s, doubling to 30 s, and started again
//! whenever the settings change (`mqtt::CHANGED`). Off, it opens no socket. Over TLS (feature
//! `tls`) with the CA certificate and the credentials stored beside the settings
//! (`settings::key::MQTT_CA`, `MQTT_CREDENTIALS`); TLS without a CA, or credentials without TLS,
//! connect nowhere and say so in the diagnostics.

use core::fmt::Write as _;

use embassy_futures::select::{select, Either};
use embassy_time::{Duration, Instant, Timer};
use embedded_storage_async::nor_flash::NorFlash;
use minimq::{Buffers, ConfigBuilder, Io, QoS, Session, Will};
use remodaq_shared::board::Shared;
use remodaq_shared::diagnostics::{mqtt, DIAGNOSTICS};
use remodaq_shared::identity::Identity;
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::{SettingsAccess, Store};
use remodaq_shared::mqtt::{binding, Config, Credentials, CA_VERSION, CHANGED};
use remodaq_shared::settings::key;
use remodaq_shared::{error, info, warn};

use crate::points::{MapModule, Options};
use crate::schedule::Point;
use crate::session::{serve, Settings, OFFLINE};
use crate::topics;

/// The first wait before connecting again.
const BACK_OFF_MIN: Duration = Duration::from_secs(1);
/// The longest wait between two attempts.
const BACK_OFF_MAX: Duration = Duration::from_secs(30);
/// The keep-alive the module asks for, s: the broker gives the will after 1.5 of these without
/// a word from the module.
pub const KEEP_ALIVE_S: u16 = 10;
/// How long the broker keeps the session (and the QoS 1 publications in flight) after the link
/// breaks, s.
const SESSION_EXPIRY_S: u32 = 300;
/// The session's receive buffer: a command is at most [`crate::command::MAX_COMMAND`] bytes and
/// its topic at most 76; a larger one, up to this, is read and refused (counted). (The STM32
/// 8350's CCM has no room for more: docs/mqtt.md, "Sizes".)
pub const RX_BUFFER: usize = 512;
/// The session's transmit buffer: the packets being written and the QoS 1 publications in
/// flight (minimq keeps at most 8, each at most about 350 bytes), until the broker acknowledges
/// them.
pub const TX_BUFFER: usize = 2048;
/// A schedule per point: the most a module has (the 8350's 12 DIs and 6 DOs).
const POINTS: usize = 18;

/// How a board reaches the broker.
#[allow(async_fn_in_trait)]
pub trait Connector {
    /// An open connection.
    type Io<'a>: Io
    where
        Self: 'a;
    /// Opens a TCP connection to `broker`:`port`; `None` (logged by the board) if it could not.
    /// TLS, where the settings ask for it, is the service's, over this connection.
    async fn connect(&mut self, broker: [u8; 4], port: u16) -> Option<Self::Io<'_>>;
    /// Closes the connection the last [`connect`](Self::connect) opened, if it is still open
    /// (the session was dropped: the settings changed), so that the broker gives the will at
    /// once. A connection that closes itself when dropped has nothing to do.
    async fn close(&mut self) {}
}

/// The board's side of the service beyond the connection.
pub struct Board<'a> {
    /// Milliseconds since 1970, or `None` before the module has a time (`time` in payloads).
    pub time_ms: fn() -> Option<u64>,
    /// Settings that override the stored ones (the simulator's `--mqtt`).
    pub imposed: Option<Config>,
    /// TLS's record buffers, [`TLS_BUFFER`] bytes (none without TLS): the caller's, in its
    /// task's storage, so that no future holding them is moved through the stack.
    pub tls_buffer: &'a mut [u8],
}

/// The CA certificate as the service holds it: up to `MAX_CA` bytes where TLS is built, none
/// in an image without it (whose TLS settings are then not usable).
#[cfg(feature = "tls")]
type Ca = heapless::Vec<u8, { remodaq_shared::mqtt::MAX_CA }>;
#[cfg(not(feature = "tls"))]
type Ca = heapless::Vec<u8, 0>;

/// TLS's record buffers (`crate::tls::BUFFER`; none without TLS).
#[cfg(feature = "tls")]
pub const TLS_BUFFER: usize = crate::tls::BUFFER;
/// TLS's record buffers (none without TLS).
#[cfg(not(feature = "tls"))]
pub const TLS_BUFFER: usize = 0;

/// Serves MQTT for ever (see the module's documentation).
pub async fn run<A: RegisterMap + SettingsAccess, F: NorFlash, C: Connector>(
    board: Board<'_>,
    connector: &mut C,
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    identity: Identity,
) -> ! {
    #[cfg(feature = "tls")]
    crate::tls::BoardClock::set(board.time_ms);
    loop {
        let mut ca = Ca::new();
        let (config, credentials) = match &board.imposed {
            Some(config) => (config.clone(), Credentials::default()),
            None => {
                let mut store = store.lock().await;
                let config: Config = store.service_record(key::MQTT).await;
                store.raw_record(key::MQTT_CA, CA_VERSION, |der| ca.extend_from_slice(der)).await.unwrap_or(());
                (config, store.service_record::<Credentials>(key::MQTT_CREDENTIALS).await)
            }
        };
        remodaq_shared::clock::set_server((config.sntp != [0; 4]).then_some((config.sntp, config.sntp_port)));
        if !config.on {
            DIAGNOSTICS.mqtt_state(mqtt::OFF);
            info!("mqtt: off");
        } else if config.tls && ca.is_empty() {
            DIAGNOSTICS.mqtt_state(mqtt::UNUSABLE);
            warn!("mqtt: TLS without a CA certificate stored (or in an image without TLS): not connected");
        } else if !credentials.user.is_empty() && (!config.tls || credentials.binding != binding(&config, &ca)) {
            DIAGNOSTICS.mqtt_state(mqtt::UNUSABLE);
            DIAGNOSTICS.mqtt_event(mqtt::PLAIN_CREDENTIALS);
            warn!("mqtt: credentials are sent only inside TLS, to the broker they were stored for: not connected");
        } else {
            DIAGNOSTICS.mqtt_state(mqtt::CONNECTING);
            let configured = Configured { config: &config, credentials: &credentials, ca: &ca, time_ms: board.time_ms };
            let tls = &mut *board.tls_buffer;
            {
                // Made in place: passed by value, this large future would be copied through the
                // stack.
                let sessions = core::pin::pin!(sessions(&configured, tls, connector, map, identity));
                match select(sessions, CHANGED.wait()).await {
                    Either::First(never) => match never {},
                    Either::Second(()) => info!("mqtt: the settings changed: starting again"),
                }
            }
            connector.close().await;
            continue;
        }
        CHANGED.wait().await;
    }
}

/// What one configuration's sessions use.
struct Configured<'a> {
    config: &'a Config,
    credentials: &'a Credentials,
    ca: &'a [u8],
    time_ms: fn() -> Option<u64>,
}

/// One configuration's sessions, reconnecting for ever.
async fn sessions<A: RegisterMap, C: Connector>(
    configured: &Configured<'_>,
    tls_buffer: &mut [u8],
    connector: &mut C,
    map: &'static Shared<A>,
    identity: Identity,
) -> core::convert::Infallible {
    let Configured { config, credentials, ca, time_ms } = *configured;
    let prefix = if config.prefix.is_empty() {
        topics::default_prefix(identity.model, identity.mac)
    } else {
        config.prefix.clone()
    };
    let status = topics::leaf(&prefix, "status");
    let mut client_id = config.client_id.clone();
    if client_id.is_empty() {
        let mut digits = [0u8; 12];
        let mac = remodaq_protocol::web::hex(&identity.mac, &mut digits).unwrap_or("");
        // 8 + 12 characters: within MAX_CLIENT_ID.
        let _ = write!(client_id, "remodaq-{mac}");
    }
    let (mut rx, mut tx) = ([0u8; RX_BUFFER], [0u8; TX_BUFFER]);
    let qos = if config.at_least_once { QoS::AtLeastOnce } else { QoS::AtMostOnce };
    let will = Will::new(&status, OFFLINE.as_bytes(), &[]).map(|w| w.retained().qos(qos));
    let built = ConfigBuilder::new(Buffers::new(&mut rx, &mut tx))
        .client_id(&client_id)
        .map(|c| c.keepalive_interval(KEEP_ALIVE_S).session_expiry_interval(SESSION_EXPIRY_S))
        .and_then(|c| match credentials.user.is_empty() {
            true => Ok(c),
            // Only ever inside TLS (`run` refuses credentials with TLS off).
            false => c.auth(&credentials.user, credentials.password.as_bytes()),
        });
    let Some(built) = built.ok().and_then(|c| will.ok().and_then(|w| c.will(w).ok())) else {
        error!("mqtt: the session's configuration was refused");
        loop {
            core::future::pending::<()>().await;
        }
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
        time_ms,
        options,
        last: Default::default(),
    };
    let mut schedules = [Point::new(); POINTS];
    let mut back_off = BACK_OFF_MIN;
    let [a, b, c, d] = config.broker;
    info!("mqtt: publishing to {}.{}.{}.{}:{} under {}", a, b, c, d, config.port, prefix.as_str());
    loop {
        if config.tls {
            #[cfg(feature = "tls")]
            match connector.connect(config.broker, config.port).await {
                Some(io) => {
                    use crate::tls::{BoardClock, ModuleRng, Refused, Whole, WHOLE, WRITE};
                    // The connection and its handshake made in place (this future holds them):
                    // returned or awaited by value, each was copied through the stack at every
                    // level (a frame of 41 KB).
                    let (read, write) = tls_buffer.split_at_mut(tls_buffer.len().saturating_sub(WRITE));
                    // Whole records: the session drops a read at each look.
                    let mut tls = crate::tls::connection(Whole::<_, WHOLE>::new(io), read, write);
                    let opened = {
                        let handshake =
                            crate::tls::handshake::<_, _, BoardClock>(&mut tls, ca, &config.host, ModuleRng);
                        core::pin::pin!(handshake).await
                    };
                    match opened {
                        Ok(()) => {
                            let ended = serve(&mut session, &mut tls, &settings, &mut module, &mut schedules).await;
                            warn!("mqtt: the TLS connection to the broker ended ({})", ended.as_str());
                            back_off = BACK_OFF_MIN;
                        }
                        Err(why) => {
                            let (n, text) = match why {
                                Refused::NoTime => (mqtt::NO_TIME, "no time yet: a certificate cannot be checked"),
                                Refused::Certificate => (mqtt::CERTIFICATE, "the broker's certificate was refused"),
                                Refused::Handshake => (mqtt::HANDSHAKE, "the TLS handshake failed"),
                            };
                            DIAGNOSTICS.mqtt_event(n);
                            warn!("mqtt: TLS: {}", text);
                        }
                    }
                }
                None => warn!("mqtt: the broker could not be reached"),
            }
            // `run` does not start sessions over TLS in an image without it.
            #[cfg(not(feature = "tls"))]
            let _ = (&tls_buffer, ca);
        } else {
            if let Some(io) = connector.connect(config.broker, config.port).await {
                let ended = serve(&mut session, io, &settings, &mut module, &mut schedules).await;
                warn!("mqtt: the connection to the broker ended ({})", ended.as_str());
                back_off = BACK_OFF_MIN;
            } else {
                warn!("mqtt: the broker could not be reached");
            }
        }
        DIAGNOSTICS.mqtt_state(mqtt::CONNECTING);
        DIAGNOSTICS.mqtt_event(mqtt::FAILURES);
        Timer::after(back_off).await;
        back_off = (back_off * 2).min(BACK_OFF_MAX);
    }
}
