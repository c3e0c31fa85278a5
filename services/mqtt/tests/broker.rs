//! The session against Debian's mosquitto, started here on loopback (issue #40's tests, the
//! parts that need no module): the status and the will, every point at once and then by its
//! deadband and period, the commands taken and refused. A subscriber (`mosquitto_sub`) sees
//! what the broker delivers. Needs `mosquitto` and `mosquitto-clients` (scripts/setup installs
//! them); without them each test says so and fails.

use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use async_io::Async;
use embedded_io_adapters::futures_03::FromFutures;
use minimq::{Buffers, ConfigBuilder, QoS, Session, Will};
use remodaq_mqtt::command::Command;
use remodaq_mqtt::schedule::Point;
use remodaq_mqtt::session::{serve, Module, Payload, PointTopic, Reading, Refused, Settings, OFFLINE};
use remodaq_mqtt::testing::{publish, Broker, Subscriber};
use remodaq_mqtt::topics::Kind;

/// What the test sets and sees of the fake module.
#[derive(Default)]
struct Shared {
    /// Three analog points' values, thousandths.
    values: [i64; 3],
    last: i64,
    commands: Vec<(u8, Command)>,
    refused: Vec<Refused>,
}

struct Fake(Arc<Mutex<Shared>>);

impl Module for Fake {
    fn points(&self) -> usize {
        3
    }
    fn tick(&self) -> embassy_time::Duration {
        embassy_time::Duration::from_millis(100)
    }
    async fn read(&mut self, i: usize) -> Reading {
        let value = self.0.lock().expect("lock").values[i];
        self.0.lock().expect("lock").last = value;
        Reading { topic: PointTopic::Numbered(Kind::Ai, i as u8), value, status: 0, deadband: 50 }
    }
    fn payload(&self, payload: &mut Payload) {
        use core::fmt::Write as _;
        payload.clear();
        let _ = write!(payload, "{{\"value\":{}}}", self.0.lock().expect("lock").last);
    }
    fn online(&self, payload: &mut Payload) {
        let _ = payload.push_str("{\"state\":\"online\"}");
    }
    fn outputs(&self) -> u8 {
        6
    }
    async fn command(&mut self, n: u8, command: Command) -> Result<(), ()> {
        self.0.lock().expect("lock").commands.push((n, command));
        Ok(())
    }
    fn refused(&mut self, why: Refused) {
        self.0.lock().expect("lock").refused.push(why);
    }
}

/// A transport that a test can freeze: every read and write then waits for ever, the socket
/// left open (a module that died without closing its connection).
struct Freezable {
    io: FromFutures<Async<TcpStream>>,
    frozen: Arc<AtomicBool>,
}

impl embedded_io_async::ErrorType for Freezable {
    type Error = std::io::Error;
}

impl embedded_io_async::Read for Freezable {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        if self.frozen.load(Ordering::SeqCst) {
            core::future::pending::<()>().await;
        }
        let n = self.io.read(buf).await?;
        if self.frozen.load(Ordering::SeqCst) {
            core::future::pending::<()>().await;
        }
        Ok(n)
    }
}

impl embedded_io_async::Write for Freezable {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        if self.frozen.load(Ordering::SeqCst) {
            core::future::pending::<()>().await;
        }
        self.io.write(buf).await
    }
    async fn flush(&mut self) -> Result<(), Self::Error> {
        self.io.flush().await
    }
}

const PREFIX: &str = "test/m1";
const STATUS: &str = "test/m1/status";
/// The keep-alive asked of the broker, s.
const KEEP_ALIVE_S: u16 = 2;
/// How often mosquitto looks at its clients' keep-alives, at most, ms (measured: see the will's
/// check).
const BROKER_CHECK_MS: u64 = 5_000;

/// Runs a session of the fake module against the broker on `port` in a thread of its own.
fn client(port: u16, period_ms: u32, commands: bool, shared: Arc<Mutex<Shared>>, frozen: Arc<AtomicBool>) {
    std::thread::spawn(move || {
        futures_executor::block_on(async move {
            let mut rx = [0u8; 1024];
            let mut tx = [0u8; 2048];
            let config = ConfigBuilder::new(Buffers::new(&mut rx, &mut tx))
                .client_id("rdaq-test")
                .expect("client id")
                .keepalive_interval(KEEP_ALIVE_S)
                .will(Will::new(STATUS, OFFLINE.as_bytes(), &[]).expect("will").retained().qos(QoS::AtLeastOnce))
                .expect("will");
            let mut session = Session::new(config);
            let addr = SocketAddr::from(([127, 0, 0, 1], port));
            let stream = Async::<TcpStream>::connect(addr).await.expect("the broker");
            let io = Freezable { io: FromFutures::new(stream), frozen };
            let settings = Settings { prefix: PREFIX, period_ms, at_least_once: true, commands };
            let mut schedules = [Point::new(); 3];
            let _ = serve(&mut session, io, &settings, &mut Fake(shared), &mut schedules).await;
        })
    });
}

#[test]
fn online_every_point_then_by_deadband_and_period_and_the_will() {
    let broker = Broker::start();
    let sub = Subscriber::start(broker.port);
    let shared = Arc::new(Mutex::new(Shared { values: [1_000, 2_000, 3_000], ..Default::default() }));
    let frozen = Arc::new(AtomicBool::new(false));
    client(broker.port, 3_000, false, shared.clone(), frozen.clone());

    assert_eq!(sub.next_on(STATUS, Duration::from_secs(5)), Some((false, "{\"state\":\"online\"}".into())));
    for (i, v) in [1_000, 2_000, 3_000].into_iter().enumerate() {
        assert_eq!(
            sub.next_on(&format!("test/m1/ai/{i}"), Duration::from_secs(2)),
            Some((false, format!("{{\"value\":{v}}}")))
        );
    }

    // Inside the deadband (50): nothing for ai/0 before its period (3 s from its first).
    let first = Instant::now();
    shared.lock().expect("lock").values[0] = 1_040;
    let early = sub.all_on("test/m1/ai/0", Duration::from_millis(1_500));
    assert!(early.is_empty(), "published inside the deadband: {early:?}");
    // Beyond it: within a tick or two.
    shared.lock().expect("lock").values[0] = 1_051;
    let moved = Instant::now();
    assert_eq!(sub.next_on("test/m1/ai/0", Duration::from_secs(1)), Some((false, "{\"value\":1051}".into())));
    assert!(moved.elapsed() < Duration::from_millis(500), "{:?} after the change", moved.elapsed());
    // ai/1 unchanged: again once its period is over, not before.
    let again = sub.next_on("test/m1/ai/1", Duration::from_secs(3));
    assert_eq!(again, Some((false, "{\"value\":2000}".into())));
    assert!(first.elapsed() >= Duration::from_millis(2_500), "ai/1 again after {:?}", first.elapsed());

    // A retained value: a new subscriber sees the last one at once.
    let late = Subscriber::start(broker.port);
    assert_eq!(late.next_on("test/m1/ai/0", Duration::from_secs(1)), Some((true, "{\"value\":1051}".into())));

    // The module freezes (its socket open, silent): the broker gives it up after 1.5
    // keep-alives (MQTT 5 §3.1.2.10) and publishes its will. Debian's mosquitto 2.0 looks at
    // its clients' keep-alives every few seconds (measured here: a client with a 2 s keep-alive
    // frozen was given up after 7.9-8.0 s, one with 5 s after 9.5 s): 1.5 keep-alives, its
    // 5 s, and a second for this PC.
    frozen.store(true, Ordering::SeqCst);
    let frozen_at = Instant::now();
    assert_eq!(sub.next_on(STATUS, Duration::from_secs(15)), Some((false, OFFLINE.into())));
    let limit = Duration::from_millis(1_500 * u64::from(KEEP_ALIVE_S) + BROKER_CHECK_MS + 1_000);
    eprintln!("offline {:?} after the module froze", frozen_at.elapsed());
    assert!(frozen_at.elapsed() <= limit, "offline {:?} after, over {limit:?}", frozen_at.elapsed());
}

#[test]
fn commands_taken_when_on_and_refused_when_malformed() {
    let broker = Broker::start();
    let sub = Subscriber::start(broker.port);
    let shared = Arc::new(Mutex::new(Shared::default()));
    client(broker.port, 60_000, true, shared.clone(), Arc::new(AtomicBool::new(false)));
    assert!(sub.next_on(STATUS, Duration::from_secs(5)).is_some(), "never online");
    std::thread::sleep(Duration::from_millis(300));

    publish(broker.port, "test/m1/do/1/set", r#"{"level": true}"#);
    publish(broker.port, "test/m1/do/2/set", r#"{"low_ms": 0.5, "high_ms": 1, "count": 10}"#);
    publish(broker.port, "test/m1/do/3/set", r#"{"level": "on"}"#);
    publish(broker.port, "test/m1/do/3/set", &format!("{{\"level\": true{}}}", " ".repeat(200)));
    publish(broker.port, "test/m1/do/9/set", r#"{"level": true}"#);
    let deadline = Instant::now() + Duration::from_secs(3);
    let seen = || {
        let s = shared.lock().expect("lock");
        s.commands.len() + s.refused.len()
    };
    while seen() < 5 {
        assert!(Instant::now() < deadline, "commands not all seen");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(300));
    let s = shared.lock().expect("lock");
    assert_eq!(s.commands, [(1, Command::Level(true)), (2, Command::Pulse { low: 5, high: 10, count: 10 })]);
    use remodaq_mqtt::command::Refusal;
    // do/9 is not under the subscription's filter of outputs... it is (do/+/set): refused as
    // naming no output.
    assert_eq!(
        s.refused,
        [Refused::Payload(Refusal::Malformed), Refused::Payload(Refusal::TooLong), Refused::NotTaken]
    );
}

#[test]
fn commands_ignored_when_off() {
    let broker = Broker::start();
    let sub = Subscriber::start(broker.port);
    let shared = Arc::new(Mutex::new(Shared::default()));
    client(broker.port, 60_000, false, shared.clone(), Arc::new(AtomicBool::new(false)));
    assert!(sub.next_on(STATUS, Duration::from_secs(5)).is_some(), "never online");
    publish(broker.port, "test/m1/do/1/set", r#"{"level": true}"#);
    std::thread::sleep(Duration::from_millis(800));
    let s = shared.lock().expect("lock");
    assert!(s.commands.is_empty() && s.refused.is_empty(), "a command reached a module with commands off");
}
