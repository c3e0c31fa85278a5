//! One connection's life (docs/mqtt.md): on a transport already open to the broker (TCP, or TLS
//! over it), the session connects (resumed when the broker kept it: QoS 1 publications in flight
//! go again), says `online` on `<prefix>/status` (retained; the will says `offline`), subscribes
//! to the 8350's commands when they are on, then publishes every point that is due
//! ([`Point::due`]) every [`Module::tick`] and carries out the commands that arrive, until the link
//! breaks. Reconnecting, with its back-off, is the caller's.

use embassy_futures::select::{select, Either};
use embassy_futures::yield_now;
use embassy_time::{Duration, Instant, Ticker};
use minimq::{Connection, Io, Publication, QoS, Session, TopicFilter};
use remodaq_shared::diagnostics::{mqtt, DIAGNOSTICS};

use crate::command::{Command, Refusal};
use crate::schedule::Point;
use crate::topics::{self, Kind, Topic};

/// The longest payload of a point.
pub const MAX_PAYLOAD: usize = 256;
/// A point's payload, JSON.
pub type Payload = heapless::String<MAX_PAYLOAD>;

/// What a session publishes and how.
#[derive(Clone, Copy, Debug)]
pub struct Settings<'a> {
    /// The topics' prefix ([`topics::prefix_is_valid`]).
    pub prefix: &'a str,
    /// At least one publication of each point per period, ms ([`crate::schedule::PERIOD_MS`]).
    pub period_ms: u32,
    /// At least once (QoS 1), or at most once (0).
    pub at_least_once: bool,
    /// Whether the 8350's output commands are taken.
    pub commands: bool,
}

/// A point's reading: where it is published, what the schedule compares, its payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reading {
    /// Its kind and number (`<prefix>/<kind>/<n>`), or a leaf (`<prefix>/cjc`).
    pub topic: PointTopic,
    /// Its value for the schedule (thousandths of an engineering unit, counts, levels).
    pub value: i64,
    /// Its status (a change publishes it).
    pub status: u8,
    /// How far its value moves before it is published ([`Point::due`]).
    pub deadband: u64,
}

/// Where a point is published.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PointTopic {
    /// `<prefix>/<kind>/<n>`.
    Numbered(Kind, u8),
    /// `<prefix>/<leaf>`.
    Leaf(&'static str),
}

/// The module's side of a session: its points and its outputs.
#[allow(async_fn_in_trait)]
pub trait Module {
    /// How many points there are.
    fn points(&self) -> usize;
    /// How often the points are looked at: a change is published within this (and the
    /// publication's time).
    fn tick(&self) -> Duration;
    /// Point `i` as it stands (kept for [`payload`](Self::payload)).
    async fn read(&mut self, i: usize) -> Reading;
    /// The payload of the point [`read`](Self::read) read last, written into `payload`
    /// (emptied first): only a point that is due is formatted.
    fn payload(&self, payload: &mut Payload);
    /// The `online` status payload (`{"state": "online", ...}`).
    fn online(&self, payload: &mut Payload);
    /// The outputs commands may name (6 on the 8350, 0 on the 8318).
    fn outputs(&self) -> u8;
    /// Carries out `command` on output `n`, all or nothing; `Err` when the module refused it
    /// (nothing changed).
    async fn command(&mut self, n: u8, command: Command) -> Result<(), ()>;
    /// Counts a command that was refused, and why.
    fn refused(&mut self, why: Refused);
}

/// Why a command was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refused {
    /// Its payload ([`Refusal`]).
    Payload(Refusal),
    /// The module's checks (the register map, the tripped host watchdog).
    Module,
    /// Commands are off, or the topic names no output.
    NotTaken,
}

/// Why a session ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ended {
    /// The MQTT session could not be established (refused, or the transport failed).
    Connect,
    /// The link broke or the broker went away.
    Link,
}

impl Ended {
    /// Why, in words (the log's).
    pub fn as_str(self) -> &'static str {
        match self {
            Ended::Connect => "the MQTT session could not be established",
            Ended::Link => "the link broke",
        }
    }
}

/// The will: `{"state":"offline"}`, retained, on `<prefix>/status`.
pub const OFFLINE: &str = "{\"state\":\"offline\"}";

/// Serves one connection on `io` until it ends (see the module's documentation). `schedules`
/// holds a [`Point`] per point of the module.
pub async fn serve<IO: Io, M: Module>(
    session: &mut Session<'_>,
    io: IO,
    settings: &Settings<'_>,
    module: &mut M,
    schedules: &mut [Point],
) -> Ended {
    let Ok(mut conn) = session.connect(io).await else { return Ended::Connect };
    DIAGNOSTICS.mqtt_state(mqtt::CONNECTED);
    DIAGNOSTICS.mqtt_event(mqtt::SESSIONS);
    let mut payload = Payload::new();
    module.online(&mut payload);
    let status = topics::leaf(settings.prefix, "status");
    if conn.publish(Publication::new(&status, payload.as_bytes()).qos(QoS::AtLeastOnce).retain()).await.is_err() {
        return Ended::Link;
    }
    if settings.commands && module.outputs() > 0 {
        let filter = topics::command_filter(settings.prefix);
        if conn.subscribe(&[TopicFilter::new(&filter)], &[]).await.is_err() {
            return Ended::Link;
        }
    }
    // A new connection publishes every point at once.
    for s in schedules.iter_mut() {
        s.forget();
    }
    let qos = if settings.at_least_once { QoS::AtLeastOnce } else { QoS::AtMostOnce };
    // At a fixed rate: the publications' own time does not stretch the period.
    let mut ticker = Ticker::every(module.tick());
    loop {
        if publish_due(&mut conn, settings, module, schedules, qos).await.is_err() {
            return Ended::Link;
        }
        // Until the next look: the broker's acknowledgments (each frees an in-flight slot of
        // QoS 1) and the commands, as they come.
        loop {
            let command = match select(conn.poll(), ticker.next()).await {
                Either::First(Ok(Some(inbound))) => {
                    Some(take(settings, module.outputs(), inbound.topic(), inbound.payload()))
                }
                Either::First(Ok(None)) => None,
                Either::First(Err(_)) => return Ended::Link,
                Either::Second(()) => break,
            };
            let refused = match command {
                Some(Ok((n, command))) => module.command(n, command).await.err().map(|()| Refused::Module),
                Some(Err(why)) => Some(why),
                None => None,
            };
            if let Some(why) = refused {
                module.refused(why);
            }
            // One inbound packet a poll: the acknowledgments come in bursts, one a publication
            // of the look before, and each moves the publications still in flight behind it in
            // the session's buffer; handled all in one poll they held Modbus 0.2 ms under QEMU
            // when the session shared its executor (docs/mqtt.md, "Never in the way"), as it still
            // does on the host build (the embassy boards run it on the background executor).
            yield_now().await;
        }
    }
}

/// Publishes each point that is due, retained; a point that cannot go now (no room for one more
/// publication in flight) stays due and goes at a later tick: nothing queues.
async fn publish_due<IO: Io, M: Module>(
    conn: &mut Connection<'_, '_, IO>,
    settings: &Settings<'_>,
    module: &mut M,
    schedules: &mut [Point],
    qos: QoS,
) -> Result<(), ()> {
    let mut payload = Payload::new();
    let tick = module.tick().as_millis();
    for (i, schedule) in schedules.iter_mut().enumerate().take(module.points()) {
        // One point a poll: the tasks that share the executor (Modbus, on the host build) wait
        // at most one point's reading and publication, never the whole look.
        yield_now().await;
        let r = module.read(i).await;
        let now = Instant::now().as_millis();
        // Due by its period if the next look would come after the period ran out: at least once
        // per period.
        if !schedule.due(r.value, r.status, now + tick, r.deadband, settings.period_ms) || !conn.can_publish(qos) {
            continue;
        }
        module.payload(&mut payload);
        let topic: Topic = match r.topic {
            PointTopic::Numbered(kind, n) => topics::point(settings.prefix, kind, n),
            PointTopic::Leaf(leaf) => topics::leaf(settings.prefix, leaf),
        };
        conn.publish(Publication::new(&topic, payload.as_bytes()).qos(qos).retain()).await.map_err(|_| ())?;
        schedule.published(r.value, r.status, now);
    }
    Ok(())
}

/// The command an inbound publication carries: its output and command, or why it is refused.
fn take(settings: &Settings<'_>, outputs: u8, topic: &str, payload: &[u8]) -> Result<(u8, Command), Refused> {
    match (settings.commands, topics::command_output(settings.prefix, topic, outputs)) {
        (true, Some(n)) => Command::parse(payload).map(|c| (n, c)).map_err(Refused::Payload),
        _ => Err(Refused::NotTaken),
    }
}
