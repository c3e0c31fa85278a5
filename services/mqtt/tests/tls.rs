//! TLS to mosquitto (issue #40's TLS tests): a CA and a broker certificate made here by
//! `openssl` (P-256), the broker's TLS listener with a password file; the session connects
//! through `remodaq_mqtt::tls::open` and publishes; a wrong CA, a wrong host name, an expired
//! certificate and a module without a time are refused; the password never crosses the link in
//! clear (every byte the TCP connection carried is kept and searched).

use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use async_io::Async;
use embedded_io_adapters::futures_03::FromFutures;
use minimq::{Buffers, ConfigBuilder, Session};
use remodaq_mqtt::command::Command;
use remodaq_mqtt::schedule::Point;
use remodaq_mqtt::session::{serve, Module, Payload, PointTopic, Reading, Refused, Settings};
use remodaq_mqtt::testing::{tls_broker, Broker, Subscriber, HOST, PASSWORD, USER};
use remodaq_mqtt::tls::{open, Clock, Refused as TlsRefused, Whole};
use remodaq_mqtt::topics::Kind;

/// The module's time, as the test sets it (seconds since 1970; 0: none yet).
static NOW: AtomicU64 = AtomicU64::new(0);

struct TestClock;

impl Clock for TestClock {
    fn now() -> Option<u64> {
        Some(NOW.load(Ordering::SeqCst)).filter(|t| *t != 0)
    }
}

fn unix_now() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).expect("after 1970").as_secs()
}

/// The test's random numbers (the boards use their own source).
struct Rng(u64);

impl rand_core::RngCore for Rng {
    fn next_u32(&mut self) -> u32 {
        self.next_u64() as u32
    }
    fn next_u64(&mut self) -> u64 {
        // splitmix64, seeded from the clock: enough for a test's key shares.
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn fill_bytes(&mut self, dest: &mut [u8]) {
        for chunk in dest.chunks_mut(8) {
            let v = self.next_u64().to_le_bytes();
            chunk.copy_from_slice(&v[..chunk.len()]);
        }
    }
    fn try_fill_bytes(&mut self, dest: &mut [u8]) -> Result<(), rand_core::Error> {
        self.fill_bytes(dest);
        Ok(())
    }
}

impl rand_core::CryptoRng for Rng {}

fn rng() -> Rng {
    Rng(SystemTime::now().duration_since(UNIX_EPOCH).expect("after 1970").as_nanos() as u64)
}

/// A TCP connection that keeps every byte it carried, both ways.
struct Captured {
    io: FromFutures<Async<TcpStream>>,
    seen: Arc<Mutex<Vec<u8>>>,
}

impl embedded_io_async::ErrorType for Captured {
    type Error = std::io::Error;
}

impl embedded_io_async::Read for Captured {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = self.io.read(buf).await?;
        self.seen.lock().expect("lock").extend_from_slice(&buf[..n]);
        Ok(n)
    }
}

impl embedded_io_async::Write for Captured {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let n = self.io.write(buf).await?;
        self.seen.lock().expect("lock").extend_from_slice(&buf[..n]);
        Ok(n)
    }
    async fn flush(&mut self) -> Result<(), Self::Error> {
        self.io.flush().await
    }
}

async fn tcp(port: u16, seen: Arc<Mutex<Vec<u8>>>) -> Captured {
    let stream = Async::<TcpStream>::connect(SocketAddr::from(([127, 0, 0, 1], port))).await.expect("the broker");
    Captured { io: FromFutures::new(stream), seen }
}

/// One point, value 7.
struct One;

impl Module for One {
    fn points(&self) -> usize {
        1
    }
    fn tick(&self) -> embassy_time::Duration {
        embassy_time::Duration::from_millis(100)
    }
    async fn read(&mut self, _: usize) -> Reading {
        Reading { topic: PointTopic::Numbered(Kind::Di, 0), value: 7, status: 0, deadband: 0 }
    }
    fn payload(&self, payload: &mut Payload) {
        payload.clear();
        let _ = payload.push_str("{\"value\":7}");
    }
    fn online(&self, payload: &mut Payload) {
        let _ = payload.push_str("{\"state\":\"online\"}");
    }
    fn outputs(&self) -> u8 {
        0
    }
    async fn command(&mut self, _: u8, _: Command) -> Result<(), ()> {
        Err(())
    }
    fn refused(&mut self, _: Refused) {}
}

/// Tries TLS to `port` with `ca` (a file of the broker's directory), `host` and the module's
/// time `now` (0: none).
fn attempt(broker: &Broker, ca: &str, host: &str, now: u64) -> Result<(), TlsRefused> {
    NOW.store(now, Ordering::SeqCst);
    let ca = std::fs::read(broker.dir.join(ca)).expect("the CA");
    let port = broker.port;
    futures_executor::block_on(async move {
        let (mut read, mut write) = (vec![0u8; remodaq_mqtt::tls::READ], vec![0u8; remodaq_mqtt::tls::WRITE]);
        let io = tcp(port, Arc::default()).await;
        open::<_, _, TestClock>(io, &mut read, &mut write, &ca, host, rng()).await.map(|_| ())
    })
}

#[test]
fn the_broker_is_checked_and_the_password_never_crosses_in_clear() {
    let broker = tls_broker();
    let now = unix_now();
    // Refused: another CA, another host name, a certificate expired by the module's time
    // (valid one day: two days on), no time at all.
    assert_eq!(attempt(&broker, "other.der", HOST, now), Err(TlsRefused::Certificate), "another CA");
    assert_eq!(attempt(&broker, "ca.der", "other.test", now), Err(TlsRefused::Certificate), "another name");
    assert_eq!(attempt(&broker, "ca.der", HOST, now + 2 * 86_400), Err(TlsRefused::Certificate), "expired");
    assert_eq!(attempt(&broker, "ca.der", HOST, 0), Err(TlsRefused::NoTime), "no time");
    let before = remodaq_mqtt::tls::EARLIEST - 1;
    assert_eq!(attempt(&broker, "ca.der", HOST, before), Err(TlsRefused::NoTime), "a time before this firmware's year");

    // The right CA, name and time: a session with the user's password, online, a point.
    let sub = Subscriber::with_args(
        broker.port,
        &["--cafile", &broker.dir.join("ca.pem").display().to_string(), "--insecure", "-u", USER, "-P", PASSWORD],
    );
    NOW.store(now, Ordering::SeqCst);
    let seen = Arc::new(Mutex::new(Vec::new()));
    let (ca, port, link) = (std::fs::read(broker.dir.join("ca.der")).expect("the CA"), broker.port, seen.clone());
    std::thread::spawn(move || {
        futures_executor::block_on(async move {
            let (mut read, mut write) = (vec![0u8; remodaq_mqtt::tls::READ], vec![0u8; remodaq_mqtt::tls::WRITE]);
            // Whole records, as the simulator's (`tls::in_place`): the session drops reads.
            let io = Whole::<_, { remodaq_mqtt::tls::WHOLE }>::new(tcp(port, link).await);
            let tls = open::<_, _, TestClock>(io, &mut read, &mut write, &ca, HOST, rng()).await.expect("TLS");
            let (mut rx, mut tx) = ([0u8; 1024], [0u8; 2048]);
            let config = ConfigBuilder::new(Buffers::new(&mut rx, &mut tx))
                .client_id("rdaq-tls")
                .expect("id")
                .auth(USER, PASSWORD.as_bytes())
                .expect("auth");
            let mut session = Session::new(config);
            let settings = Settings { prefix: "test/t", period_ms: 60_000, at_least_once: true, commands: false };
            let _ = serve(&mut session, tls, &settings, &mut One, &mut [Point::new()]).await;
        })
    });
    assert!(sub.next_on("test/t/status", Duration::from_secs(10)).is_some(), "never online over TLS");
    assert_eq!(sub.next_on("test/t/di/0", Duration::from_secs(2)).map(|(_, p)| p), Some("{\"value\":7}".into()));

    let link = seen.lock().expect("lock").clone();
    assert!(link.len() > 500, "the link carried {} bytes", link.len());
    assert_eq!(&link[..3], &[0x16, 0x03, 0x01], "a TLS ClientHello first");
    for secret in [PASSWORD.as_bytes(), b"test/t/status", b"online"] {
        assert!(
            !link.windows(secret.len()).any(|w| w == secret),
            "{:?} in clear on the link",
            String::from_utf8_lossy(secret)
        );
    }
}
