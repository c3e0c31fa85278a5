//! MQTT on the QEMU 8350 image (issue #40, docs/mqtt.md): the module's own session over
//! embassy-net to Debian's mosquitto on this PC (QEMU's user network: the host is 10.0.2.2),
//! set through the web console's API; and the Modbus request latency with MQTT off and with MQTT
//! publishing every point at 10 Hz.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use remodaq_mqtt::testing::{Broker, Subscriber};
use remodaq_protocol::m8350::{Point, BIT_DO};
use tokio::time::timeout;
use tokio_modbus::client::{Reader as _, Writer as _};

use crate::client::{connect, write, STEP};
use crate::discovery::PASSWORD;
use crate::guest::compared;
use crate::load::{Latencies, StallWatch};
use crate::modbus::burst;
use crate::qemu::Qemu;
use crate::stacks::{background_stack, shares_the_plan};

/// The topics' prefix the test sets.
const PREFIX: &str = "test/qemu";
/// Requests measured with MQTT off, and again with it on.
const REQUESTS: usize = 1000;
/// The period set: every point at least once per 100 ms (10 Hz).
const PERIOD_MS: u32 = 100;

/// MQTT's settings as `PUT /api/v1/mqtt` takes them: on or off, to the broker on this PC, the
/// time from the time server on this PC at `sntp` (0: none).
fn settings(on: bool, port: u16, sntp: u16) -> String {
    let sntp = if sntp == 0 { String::new() } else { format!("10.0.2.2:{sntp}") };
    format!(
        r#"{{"on":{on},"broker":"10.0.2.2","host":"","port":{port},"client_id":"","tls":false,"prefix":"{PREFIX}","period_ms":{PERIOD_MS},"qos":1,"deadbands":[0,0,0,0,0,0,0,0],"on_change":true,"commands":false,"sntp":"{sntp}"}}"#
    )
}

/// Stores MQTT's settings through the web console (logged in with the password the update checks
/// set: the factory password's refusal is the host build's test).
async fn put(web: SocketAddr, body: String) -> Result<(), String> {
    put_at(web, "/api/v1/mqtt", body).await
}

/// A signed `PUT` of `body` to `target` of the web console, answered 204.
async fn put_at(web: SocketAddr, target: &'static str, body: String) -> Result<(), String> {
    tokio::task::spawn_blocking(move || {
        use remodaq_board_host::testing::web::{log_in, request};
        let mut page = log_in(web, PASSWORD).map_err(|a| format!("login: {} {}", a.status, a.body))?;
        let headers = page.sign("PUT", target, &body);
        let answer = request(web, "PUT", target, &headers, &body);
        if answer.status == 204 {
            Ok(())
        } else {
            Err(format!("PUT {target}: {} {}", answer.status, answer.body))
        }
    })
    .await
    .map_err(|e| e.to_string())?
}

/// The measure's pace: a request every 2 ms (a busy SCADA poll), so that the 1000 span 2 s, 20
/// publications of every point.
const PACE: Duration = Duration::from_millis(2);

/// `REQUESTS` Modbus requests, one at a time at [`PACE`], each less the time this PC stalled the
/// machine.
async fn latencies(modbus: SocketAddr, log: &str) -> Result<Latencies, String> {
    let mut stream = timeout(STEP, tokio::net::TcpStream::connect(modbus))
        .await
        .map_err(|_| "connect")?
        .map_err(|e| e.to_string())?;
    let _ = stream.set_nodelay(true);
    let mut stalls = StallWatch::new(log);
    let mut measured = Latencies::default();
    let mut pace = tokio::time::interval(PACE);
    let from = std::fs::metadata(log).map_or(0, |m| m.len());
    for _ in 0..REQUESTS {
        pace.tick().await;
        let took = burst(&mut stream, 1).await?;
        measured.add(took, stalls.since());
    }
    drop(stream);
    measured.guest = crate::guest::figures(log, from, REQUESTS).await;
    Ok(measured)
}

/// Issue #40 on the embassy-net board: with MQTT off, 1000 Modbus requests measured; MQTT set on
/// through the web console (plain TCP, a 100 ms period, QoS 1): `online` on `<prefix>/status`,
/// every point published at 10 Hz at the least, a DO switched over Modbus published as Modbus
/// reads it; 1000 requests measured while it publishes; the broker restarted: `online` again and
/// the current values; MQTT set off: `offline` (the will, the module closing its connection) at
/// once.
///
/// The check on the measure: the median with MQTT on within 1.5x off, or 0.1 ms ([`within`]).
/// The worsts are printed (the issue's figure, worst within 1.5x off): under QEMU the worst of
/// 1000 is this PC's as much as the firmware's (off alone gave 1.0 to 3.8 ms over six runs
/// here: `load.rs` says more), so it is reported, not counted.
pub(crate) async fn mqtt_publishing(modbus: SocketAddr, web: SocketAddr, log: &str) -> Result<(), String> {
    let broker = tokio::task::spawn_blocking(Broker::start).await.map_err(|e| e.to_string())?;
    let port = broker.port;
    let off = latencies(modbus, log).await?;
    let sub = tokio::task::spawn_blocking(move || Subscriber::start(port)).await.map_err(|e| e.to_string())?;
    let time = TimeServer::start()?;
    put(web, settings(true, port, time.port)).await?;
    let (sub, online) = tokio::task::spawn_blocking(move || {
        let online = sub.next_on(&format!("{PREFIX}/status"), Duration::from_secs(10));
        (sub, online)
    })
    .await
    .map_err(|e| e.to_string())?;
    match online {
        Some((_, p)) if p.contains(r#""state":"online""#) && p.contains(r#""model":"8350""#) => {}
        other => return Err(format!("no online status within 10 s: {other:?}")),
    }

    // DI0 counts (counter mode, running: the QEMU board's 1 kHz square wave on DI0), so that it
    // changes at every look.
    let mut ctx = connect(modbus).await?;
    write(&mut ctx, Point::DiMode(0).addr().1, &[1]).await?;
    let (_, run) = Point::CounterRun(0).addr();
    timeout(STEP, ctx.write_single_coil(run, true))
        .await
        .map_err(|_| "no answer")?
        .map_err(|e| e.to_string())?
        .map_err(|e| format!("{e:?}"))?;
    // DO5 on over Modbus: published as Modbus reads it.
    timeout(STEP, ctx.write_single_coil(BIT_DO + 5, true))
        .await
        .map_err(|_| "no answer")?
        .map_err(|e| e.to_string())?
        .map_err(|e| format!("{e:?}"))?;
    let read =
        timeout(STEP, ctx.read_coils(BIT_DO + 5, 1)).await.map_err(|_| "no answer")?.map_err(|e| e.to_string())?;
    let (sub, published) = tokio::task::spawn_blocking(move || {
        let deadline = Instant::now() + Duration::from_secs(2);
        let mut last = None;
        while let Some(left) = deadline.checked_duration_since(Instant::now()) {
            match sub.next_on(&format!("{PREFIX}/do/5"), left) {
                Some((_, p)) if p.contains(r#""state":true"#) => {
                    last = Some(p);
                    break;
                }
                Some((_, p)) => last = Some(p),
                None => break,
            }
        }
        (sub, last)
    })
    .await
    .map_err(|e| e.to_string())?;
    match (&read, &published) {
        (Ok(r), Some(p)) if r == &[true] && p.contains(r#""state":true"#) => {}
        _ => return Err(format!("DO5 on: Modbus reads {read:?}, MQTT published {published:?}")),
    }

    // The time of day from the time server (SNTP): the payloads' `time`, this PC's within 5 s.
    let (sub, stamped) = tokio::task::spawn_blocking(move || {
        let deadline = Instant::now() + Duration::from_secs(20);
        let mut last = None;
        while let Some(left) = deadline.checked_duration_since(Instant::now()) {
            match sub.next_on(&format!("{PREFIX}/do/5"), left) {
                Some((_, p)) if !p.contains(r#""time":null"#) => {
                    last = Some(p);
                    break;
                }
                Some(p) => last = Some(p.1),
                None => break,
            }
        }
        (sub, last)
    })
    .await
    .map_err(|e| e.to_string())?;
    let now_ms = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_millis() as i64);
    let time_ms = stamped
        .as_deref()
        .and_then(|p| p.split("\"time\":").nth(1))
        .and_then(|t| t.trim_end_matches('}').parse::<i64>().ok());
    match time_ms {
        Some(t) if (t - now_ms).abs() < 5_000 => {
            println!("  the time of day from SNTP: the payloads' time {} ms from this PC's", t - now_ms)
        }
        _ => return Err(format!("no time of day from the time server within 20 s (DO5's payload: {stamped:?})")),
    }
    drop(time);

    // The measure while every point is published at 10 Hz, the publications counted meanwhile.
    sub.pending_topics();
    let started = Instant::now();
    let on = latencies(modbus, log).await?;
    let measured_for = started.elapsed();
    let topics = sub.pending_topics();
    let di0 = topics.iter().filter(|t| *t == &format!("{PREFIX}/di/0")).count();
    let slowest = published_least(&topics, PREFIX);
    let _ = timeout(STEP, ctx.write_single_coil(BIT_DO + 5, false)).await;
    let do5 =
        timeout(STEP, ctx.read_coils(BIT_DO + 5, 1)).await.map_err(|_| "no answer")?.map_err(|e| e.to_string())?;
    drop(ctx);

    // The broker restarted, down 1 s and keeping nothing (no persistence): the module back by
    // itself with its back-off (1 s, doubling), `online` again and every point's current value
    // published (DO5's as Modbus reads it now), on a subscriber that came after the restart.
    drop(sub);
    let (broker, sub, back) = tokio::task::spawn_blocking(move || {
        let mut broker = broker;
        broker.restart(Duration::from_secs(1));
        let restarted = Instant::now();
        let sub = Subscriber::start(port);
        let online = sub.next_on(&format!("{PREFIX}/status"), Duration::from_secs(15));
        let do5 = online.as_ref().and_then(|_| sub.next_on(&format!("{PREFIX}/do/5"), Duration::from_secs(2)));
        (broker, sub, (online, do5, restarted.elapsed()))
    })
    .await
    .map_err(|e| e.to_string())?;
    let expected = match do5.map_err(|e| format!("{e:?}"))?.as_slice() {
        [false] => r#""state":false"#,
        [true] => r#""state":true"#,
        other => return Err(format!("DO5 read {other:?} over Modbus")),
    };
    match back {
        (Some((_, online)), Some((_, do5)), took)
            if online.contains(r#""state":"online""#) && do5.contains(expected) =>
        {
            println!(
                "  the broker restarted (down 1 s): online again and DO5's current value {:.1} s after",
                took.as_secs_f64()
            )
        }
        (online, do5, _) => {
            return Err(format!("after the broker's restart: status {online:?}, DO5 {do5:?} (Modbus: {expected})"))
        }
    }

    put(web, settings(false, port, 0)).await?;
    let offline = tokio::task::spawn_blocking(move || {
        let deadline = Instant::now() + Duration::from_secs(5);
        while let Some(left) = deadline.checked_duration_since(Instant::now()) {
            match sub.next_on(&format!("{PREFIX}/status"), left) {
                Some((_, p)) if p.contains(r#""state":"offline""#) => return Ok(()),
                Some(_) => {}
                None => break,
            }
        }
        Err("no offline status within 5 s of MQTT set off".to_string())
    })
    .await
    .map_err(|e| e.to_string())?;
    drop(broker);

    let secs = measured_for.as_secs_f64();
    let (rate, di0_rate, slowest_rate) = (topics.len() as f64 / secs, di0 as f64 / secs, slowest.0 as f64 / secs);
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    println!(
        "  Modbus, {REQUESTS} requests at one per {PACE:?} with MQTT off: median {:.3} ms, 99 % {:.3} ms, worst {:.3} ms ({} during a stall of the machine); with MQTT publishing every point at 10 Hz at the least (plain TCP, QoS 1; {} publications in {secs:.1} s, {rate:.0}/s: DI0, changing all the time, {di0_rate:.0}/s; the point published least, {}, {slowest_rate:.1}/s): median {:.3} ms, 99 % {:.3} ms, worst {:.3} ms ({} during a stall; worst {:.2}x off's)",
        ms(off.median()),
        ms(off.quantile(99)),
        ms(off.worst()),
        off.stalled,
        topics.len(),
        slowest.1,
        ms(on.median()),
        ms(on.quantile(99)),
        ms(on.worst()),
        on.stalled,
        on.worst().as_secs_f64() / off.worst().as_secs_f64().max(1e-9)
    );
    println!("  the same measured in the guest (its wall clock): {}", compared(off.guest, on.guest));
    offline?;
    // Every point at least once per period (the measure's edges: one publication less); DI0 at
    // every look of 10 ms (the same less a tenth for this PC's scheduling of QEMU).
    let least = (secs * 1000.0 / f64::from(PERIOD_MS)).floor() as usize - 1;
    if slowest.0 < least {
        return Err(format!(
            "{} published {} times in {secs:.1} s: at least once per {PERIOD_MS} ms is {least}",
            slowest.1, slowest.0
        ));
    }
    if di0_rate < 90.0 {
        return Err(format!("DI0, changing all the time, published {di0_rate:.0}/s: every look of 10 ms is 100/s"));
    }
    // The median counted, the 99 % printed: with the main executor polled from an interrupt
    // (this stop), the 99 % publishing ranged from 1.09x to 1.9x off's over eight runs under QEMU,
    // where off's alone ranges from 0.37 to 0.69 ms (docs/mqtt.md, "Never in the way").
    within(&off, &on, "")
}

/// A time server (SNTP, RFC 4330) on this PC's loopback, answering every request with this
/// PC's clock, until dropped: the module's time of day for TLS (QEMU's user network: the
/// module asks 10.0.2.2 at this port).
struct TimeServer {
    port: u16,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
}

impl TimeServer {
    fn start() -> Result<Self, String> {
        use std::sync::atomic::{AtomicBool, Ordering};
        let socket = std::net::UdpSocket::bind("127.0.0.1:0").map_err(|e| e.to_string())?;
        let port = socket.local_addr().map_err(|e| e.to_string())?.port();
        let _ = socket.set_read_timeout(Some(Duration::from_millis(200)));
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let stopped = stop.clone();
        std::thread::spawn(move || {
            let mut request = [0u8; 48];
            while !stopped.load(Ordering::Relaxed) {
                let Ok((48, from)) = socket.recv_from(&mut request) else { continue };
                // NTP's era starts in 1900: 2 208 988 800 s before 1970.
                let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
                let secs = (now.as_secs() + 2_208_988_800) as u32;
                let fraction = ((u64::from(now.subsec_nanos()) << 32) / 1_000_000_000) as u32;
                let mut answer = [0u8; 48];
                answer[0] = 0x24; // LI 0, version 4, mode 4 (server)
                answer[1] = 1; // stratum 1
                answer[12..16].copy_from_slice(b"RDAQ");
                answer[24..32].copy_from_slice(&request[40..48]); // the request's transmit time
                for at in [16, 32, 40] {
                    answer[at..at + 4].copy_from_slice(&secs.to_be_bytes());
                    answer[at + 4..at + 8].copy_from_slice(&fraction.to_be_bytes());
                }
                let _ = socket.send_to(&answer, from);
            }
        });
        Ok(Self { port, stop })
    }
}

impl Drop for TimeServer {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
    }
}

/// The point published least often but DI0 (a 1 kHz square wave, its counter running: it
/// changes all the time, so it is published at every look), among `topics` under `prefix`:
/// how many times, and which.
fn published_least(topics: &[String], prefix: &str) -> (usize, String) {
    (0..12)
        .map(|n| format!("di/{n}"))
        .chain((0..6).map(|n| format!("do/{n}")))
        .skip(1)
        .map(|p| (topics.iter().filter(|t| **t == format!("{prefix}/{p}")).count(), p))
        .min()
        .unwrap_or_default()
}

/// The check on a measure: the median with MQTT publishing (`on`) within 1.5x off's, or at
/// most [`SLACK`] above it. Under QEMU a request's median is 0.07 to 0.17 ms from run to run on
/// this PC, so 1.5x of a low one is 35 µs: two runs of December 2026 failed by that (0.068 ->
/// 0.107 ms plain, 0.085 -> 0.134 ms over TLS) where the other runs seen were within 0.8x-1.3x
/// (docs/mqtt.md, "Never in the way"). A stall the issue is about (the handshake's 37.9 ms) is
/// 379 times the slack.
fn within(off: &Latencies, on: &Latencies, how: &str) -> Result<(), String> {
    let (off, on) = (off.median(), on.median());
    if on > off.mul_f64(1.5) && on > off + SLACK {
        return Err(format!(
            "the median with MQTT publishing{how}, {on:?}, is over 1.5x off's, {off:?}, and more than {SLACK:?} above it"
        ));
    }
    Ok(())
}

/// How far the median with MQTT publishing may be above off's whatever the ratio ([`within`]).
const SLACK: Duration = Duration::from_micros(100);

/// A span of the guest's time in QEMU's log: its length and its end, µs.
type Span = (u64, u64);

/// The polls of the background executor and the main one's tasks that QEMU's log says took long
/// (`a task poll of the main executor took N us, at T us`, boards/qemu `time.rs`) in `log` from byte `from`
/// on: the background's (the TLS handshake's arithmetic) as they are, and the main executor's
/// during one of them, but those during which this PC stalled the machine (`the machine
/// stalled`). Each (length, end), µs of the guest's clock.
fn long_polls(log: &str, from: u64) -> (Vec<Span>, Vec<Span>) {
    let text = std::fs::read(log).unwrap_or_default();
    let text = String::from_utf8_lossy(text.get(from as usize..).unwrap_or(&[]));
    let spans = |prefix: &str| -> Vec<Span> {
        text.lines()
            .filter_map(|l| l.strip_prefix(prefix))
            .filter_map(|r| {
                let mut words = r.split(' ');
                let took = words.next()?.parse().ok()?;
                let at = words.nth(2)?.parse().ok()?;
                Some((took, at))
            })
            .collect()
    };
    let overlap = |(a, at): Span, (b, bt): Span| at.saturating_sub(a) < bt && bt.saturating_sub(b) < at;
    let stalls = spans("qemu board: the machine stalled ");
    let background = spans("qemu board: a poll of the background executor took ");
    let main = spans("qemu board: a task poll of the main executor took ")
        .into_iter()
        .filter(|&p| background.iter().any(|&b| overlap(p, b)) && !stalls.iter().any(|&s| overlap(p, s)))
        .collect();
    (background, main)
}

/// Issue #40 over TLS on the embassy-net board: a broker with only a TLS listener, a password
/// file and an ACL (certificates made by openssl), a time server on this PC; the module set
/// through the web console (TLS on, the broker's name, the time server, the CA, the credentials
/// sealed): online over TLS, every point at least 10 times a second; no task poll of the main
/// executor of 3 ms or more while the background executor computed the handshake (QEMU's log:
/// the issue's figure, the longest stall, printed); the background executor's stack within its
/// own; 1000 Modbus requests with MQTT off, then 1000 while MQTT publishes over TLS: the
/// client's median within 1.5x or 0.1 ms ([`within`]; its 99th percentile and worst printed:
/// this PC's as much as the firmware's), and the guest's own measure of each request beside
/// (`crate::guest`: the whole run starts this check on a QEMU counting instructions, so the
/// figure is the firmware's), printed: its worst, the issue's figure, is the rare 0.4 ms poll of
/// the 8350's I/O loop in whichever phase a request meets it (docs/mqtt.md, "Never in the
/// way"); the module lost ([`offline_when_lost`]); set off at the end.
pub(crate) async fn mqtt_over_tls(modbus: SocketAddr, web: SocketAddr, log: &str, qemu: &Qemu) -> Result<(), String> {
    use remodaq_mqtt::testing::{make_pki, HOST, PASSWORD as BROKER_PASSWORD, USER};
    const TLS_PREFIX: &str = "test/qemu-tls";
    let broker = tokio::task::spawn_blocking(|| {
        Broker::with(|port, dir| {
            make_pki(dir);
            let _ = std::fs::write(dir.join("acl"), format!("user {USER}\ntopic readwrite {TLS_PREFIX}/#\n"));
            let d = dir.display();
            format!(
                "listener {port} 127.0.0.1\ncafile {d}/ca.pem\ncertfile {d}/server.pem\nkeyfile {d}/server.key\n\
                 allow_anonymous false\npassword_file {d}/passwords\nacl_file {d}/acl\n"
            )
        })
    })
    .await
    .map_err(|e| e.to_string())?;
    let time = TimeServer::start()?;
    let (port, dir) = (broker.port, broker.dir.clone());
    let sub = tokio::task::spawn_blocking(move || {
        let ca = dir.join("ca.pem").display().to_string();
        Subscriber::with_args(
            port,
            &["--cafile", &ca, "--insecure", "-u", USER, "-P", BROKER_PASSWORD, "-t", &format!("{TLS_PREFIX}/#")],
        )
    })
    .await
    .map_err(|e| e.to_string())?;
    let off = latencies(modbus, log).await?;

    // The settings, the CA, then the credentials: the handshake starts with the last.
    let pem = std::fs::read_to_string(broker.dir.join("ca.pem")).map_err(|e| e.to_string())?;
    let tls_settings = format!(
        r#"{{"on":true,"broker":"10.0.2.2","host":"{HOST}","port":{port},"client_id":"","tls":true,"prefix":"{TLS_PREFIX}","period_ms":{PERIOD_MS},"qos":1,"deadbands":[0,0,0,0,0,0,0,0],"on_change":true,"commands":false,"sntp":"10.0.2.2:{}"}}"#,
        time.port
    );
    put(web, tls_settings).await?;
    put_at(web, "/api/v1/mqtt/ca", format!(r#"{{"pem":"{}"}}"#, pem.split_whitespace().collect::<Vec<_>>().join(" ")))
        .await?;
    let sealed = tokio::task::spawn_blocking(move || {
        let mut page =
            remodaq_board_host::testing::web::log_in(web, PASSWORD).map_err(|a| format!("login: {}", a.status))?;
        let answer = page.put_mqtt_credentials(web, USER, BROKER_PASSWORD);
        if answer.status == 204 {
            Ok(())
        } else {
            Err(format!("PUT /api/v1/mqtt/credentials: {} {}", answer.status, answer.body))
        }
    });
    sealed.await.map_err(|e| e.to_string())??;
    // The handshake's window: from the credentials stored (the web console's own work for them,
    // the login and the unsealing, done) to the module online.
    let log_from = std::fs::metadata(log).map_or(0, |m| m.len());
    let asked = Instant::now();
    let (sub, online) = tokio::task::spawn_blocking(move || {
        let online = sub.next_on(&format!("{TLS_PREFIX}/status"), Duration::from_secs(60));
        (sub, online)
    })
    .await
    .map_err(|e| e.to_string())?;
    let handshake = asked.elapsed();
    let polls = long_polls(log, log_from);
    let mut ctx = connect(modbus).await?;
    let diagnostics = timeout(STEP, ctx.read_holding_registers(remodaq_protocol::diag::REG_MQTT, 10)).await;
    drop(ctx);
    match online {
        Some((_, p)) if p.contains(r#""state":"online""#) => {}
        other => {
            return Err(format!(
                "no online status over TLS within 60 s: {other:?}; MQTT's diagnostics 40328-40337: {diagnostics:?}"
            ))
        }
    }
    let (background, main) = polls;
    let lengths = |polls: &[Span]| polls.iter().map(|p| p.0).collect::<Vec<_>>();
    let longest = main.iter().map(|p| p.0).max().unwrap_or(0);
    println!(
        "  over TLS: online {:.1} s after the credentials were stored; the handshake's arithmetic, the background executor's polls of 3 ms or more: {:?} us; the main executor's task polls of 3 ms or more during them, but during a stall of the machine: {} (the longest {:.1} ms: {:?} us)",
        handshake.as_secs_f64(),
        lengths(&background),
        main.len(),
        longest as f64 / 1e3,
        lengths(&main),
    );
    if background.is_empty() {
        return Err("no poll of the background executor of 3 ms or more: the handshake ran elsewhere".into());
    }
    if !main.is_empty() {
        return Err(format!(
            "a task held the main executor for {longest} us during the TLS handshake (3 ms is the most)"
        ));
    }

    sub.pending_topics();
    let started = Instant::now();
    let on = latencies(modbus, log).await?;
    let secs = started.elapsed().as_secs_f64();
    let topics = sub.pending_topics();
    let slowest = published_least(&topics, TLS_PREFIX);
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    println!(
        "  Modbus, {REQUESTS} requests at one per {PACE:?} with MQTT off: median {:.3} ms, 99 % {:.3} ms, worst {:.3} ms; with MQTT publishing over TLS ({} publications in {secs:.1} s; the point published least, {}, {:.1}/s): median {:.3} ms, 99 % {:.3} ms, worst {:.3} ms (worst {:.2}x off's; {} and {} requests during a stall of the machine)",
        ms(off.median()),
        ms(off.quantile(99)),
        ms(off.worst()),
        topics.len(),
        slowest.1,
        slowest.0 as f64 / secs,
        ms(on.median()),
        ms(on.quantile(99)),
        ms(on.worst()),
        on.worst().as_secs_f64() / off.worst().as_secs_f64().max(1e-9),
        off.stalled,
        on.stalled
    );
    println!(
        "  the same measured in the guest (its clock counting its instructions): {}",
        compared(off.guest, on.guest)
    );
    let sub = offline_when_lost(qemu, sub, format!("{TLS_PREFIX}/status")).await?;
    put(web, settings(false, port, 0)).await?;
    drop(sub);
    drop(broker);
    // Read now: the board says its stacks' marks once a second.
    let background = background_stack(log);
    println!(
        "  the background executor's stack (the handshake's): {} of {} bytes used at the most",
        background.0, background.1
    );
    if background.0 == 0 || background.0 + 1024 > background.1 {
        return Err(format!(
            "the background executor's stack: {} of {} bytes used (1 KiB spare is the least)",
            background.0, background.1
        ));
    }
    shares_the_plan(background.0, log)?;
    let least = (secs * 1000.0 / f64::from(PERIOD_MS)).floor() as usize - 1;
    if slowest.0 < least {
        return Err(format!(
            "over TLS, {} published {} times in {secs:.1} s: at least once per {PERIOD_MS} ms is {least}",
            slowest.1, slowest.0
        ));
    }
    within(&off, &on, " over TLS")
}

/// The module lost (QEMU stopped, [`Qemu::signal`]): the broker publishes its will, `offline` on
/// `status`, within 1.5 keep-alives (MQTT 5 §3.1.2.10), plus the broker's own lateness in giving
/// up a silent client (Debian's mosquitto 2.0.11: 4.2 and 5.9 s after 1.5 keep-alives in this
/// check's first runs, 5 s with a 2 s keep-alive: docs/mqtt.md) and this PC's: 8 s; then QEMU
/// runs on.
async fn offline_when_lost(qemu: &Qemu, sub: Subscriber, status: String) -> Result<Subscriber, String> {
    use remodaq_mqtt::service::KEEP_ALIVE_S;
    let limit = Duration::from_millis(1_500 * u64::from(KEEP_ALIVE_S) + 8_000);
    sub.pending_topics();
    qemu.signal(true)?;
    let lost = Instant::now();
    let waited = tokio::task::spawn_blocking(move || {
        while lost.elapsed() < limit + Duration::from_secs(5) {
            if let Some((_, p)) = sub.next_on(&status, Duration::from_secs(1)) {
                if p.contains(r#""state":"offline""#) {
                    return (sub, Some(lost.elapsed()));
                }
            }
        }
        (sub, None)
    })
    .await;
    qemu.signal(false)?;
    let (sub, offline) = waited.map_err(|e| e.to_string())?;
    let Some(after) = offline else { return Err(format!("the module lost: no offline within {limit:?}")) };
    println!(
        "  the module lost (QEMU stopped): offline {:.1} s after (at most 1.5 keep-alives of {KEEP_ALIVE_S} s and the broker's and this PC's 8 s)",
        after.as_secs_f64()
    );
    if after > limit {
        return Err(format!("the module lost: offline {after:?} after, over {limit:?}"));
    }
    Ok(sub)
}
