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
use crate::load::{Latencies, StallWatch};
use crate::modbus::burst;

/// The topics' prefix the test sets.
const PREFIX: &str = "test/qemu";
/// Requests measured with MQTT off, and again with it on.
const REQUESTS: usize = 1000;
/// The period set: every point at least once per 100 ms (10 Hz).
const PERIOD_MS: u32 = 100;

/// MQTT's settings as `PUT /api/v1/mqtt` takes them: on or off, to the broker on this PC.
fn settings(on: bool, port: u16) -> String {
    format!(
        r#"{{"on":{on},"broker":"10.0.2.2","host":"","port":{port},"client_id":"","tls":false,"prefix":"{PREFIX}","period_ms":{PERIOD_MS},"qos":1,"deadbands":[0,0,0,0,0,0,0,0],"on_change":true,"commands":false}}"#
    )
}

/// Stores MQTT's settings through the web console (logged in with the password the update checks
/// set: the factory password's refusal is the host build's test).
async fn put(web: SocketAddr, body: String) -> Result<(), String> {
    tokio::task::spawn_blocking(move || {
        use remodaq_board_host::testing::web::{log_in, request};
        let mut page = log_in(web, PASSWORD).map_err(|a| format!("login: {} {}", a.status, a.body))?;
        let headers = page.sign("PUT", "/api/v1/mqtt", &body);
        let answer = request(web, "PUT", "/api/v1/mqtt", &headers, &body);
        if answer.status == 204 {
            Ok(())
        } else {
            Err(format!("PUT /api/v1/mqtt: {} {}", answer.status, answer.body))
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
    for _ in 0..REQUESTS {
        pace.tick().await;
        let took = burst(&mut stream, 1).await?;
        measured.add(took, stalls.since());
    }
    Ok(measured)
}

/// Issue #40 on the embassy-net board: with MQTT off, 1000 Modbus requests measured; MQTT set on
/// through the web console (plain TCP, a 100 ms period, QoS 1): `online` on `<prefix>/status`,
/// every point published at 10 Hz at the least, a DO switched over Modbus published as Modbus
/// reads it; 1000 requests measured while it publishes; MQTT set off: `offline` (the will, the
/// module closing its connection) at once.
///
/// The check on the measure: the median and the 99th percentile with MQTT on within 1.5x off.
/// The worsts are printed (the issue's figure, worst within 1.5x off): under QEMU the worst of
/// 1000 is this PC's as much as the firmware's (off alone gave 1.0 to 3.8 ms over six runs
/// here: `load.rs` says more), so it is reported, not counted.
pub(crate) async fn mqtt_publishing(modbus: SocketAddr, web: SocketAddr, log: &str) -> Result<(), String> {
    let broker = tokio::task::spawn_blocking(Broker::start).await.map_err(|e| e.to_string())?;
    let port = broker.port;
    let off = latencies(modbus, log).await?;
    let sub = tokio::task::spawn_blocking(move || Subscriber::start(port)).await.map_err(|e| e.to_string())?;
    put(web, settings(true, port)).await?;
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

    // The measure while every point is published at 10 Hz, the publications counted meanwhile.
    sub.pending_topics();
    let started = Instant::now();
    let on = latencies(modbus, log).await?;
    let measured_for = started.elapsed();
    let topics = sub.pending_topics();
    let di0 = topics.iter().filter(|t| *t == &format!("{PREFIX}/di/0")).count();
    // The points but DI0 (a 1 kHz square wave, its counter running: it changes all the time,
    // so it is published at every look, 100 a second).
    let slowest = (0..12)
        .map(|n| format!("di/{n}"))
        .chain((0..6).map(|n| format!("do/{n}")))
        .skip(1)
        .map(|p| (topics.iter().filter(|t| **t == format!("{PREFIX}/{p}")).count(), p))
        .min()
        .unwrap_or_default();
    let _ = timeout(STEP, ctx.write_single_coil(BIT_DO + 5, false)).await;
    drop(ctx);

    put(web, settings(false, port)).await?;
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
    for (what, off, on) in [("median", off.median(), on.median()), ("99 %", off.quantile(99), on.quantile(99))] {
        if on.as_secs_f64() > off.as_secs_f64() * 1.5 {
            return Err(format!("the {what} with MQTT publishing, {on:?}, is over 1.5x off's, {off:?}"));
        }
    }
    Ok(())
}
