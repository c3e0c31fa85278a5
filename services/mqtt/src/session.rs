//! One connection's life (docs/mqtt.md): on a transport already open to the broker (TCP, or TLS
//! over it), the session connects (resumed when the broker kept it: QoS 1 publications in flight
//! go again), says `online` on `<prefix>/status` (retained; the will says `offline`), subscribes
//! to the 8350's commands when they are on, then publishes every point that is due
//! ([`Point::due`]) every [`TICK`] and carries out the commands that arrive, until the link
//! breaks. Reconnecting, with its back-off, is the caller's.

use embassy_futures::select::{select, Either};
use embassy_time::{Duration, Instant, Timer};
use minimq::{Connection, Io, Publication, QoS, Session, TopicFilter};

use crate::command::{Command, Refusal};
use crate::schedule::Point;
use crate::topics::{self, Kind, Topic};

/// How often the points are looked at.
pub const TICK: Duration = Duration::from_millis(100);
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
    /// Point `i` as it stands, its payload written into `payload` (emptied first).
    async fn read(&mut self, i: usize, payload: &mut Payload) -> Reading;
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
    loop {
        if publish_due(&mut conn, settings, module, schedules, qos).await.is_err() {
            return Ended::Link;
        }
        let command = match select(conn.poll(), Timer::after(TICK)).await {
            Either::First(Ok(Some(inbound))) => {
                Some(take(settings, module.outputs(), inbound.topic(), inbound.payload()))
            }
            Either::First(Ok(None)) | Either::Second(()) => None,
            Either::First(Err(_)) => return Ended::Link,
        };
        let refused = match command {
            Some(Ok((n, command))) => module.command(n, command).await.err().map(|()| Refused::Module),
            Some(Err(why)) => Some(why),
            None => None,
        };
        if let Some(why) = refused {
            module.refused(why);
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
    for (i, schedule) in schedules.iter_mut().enumerate().take(module.points()) {
        payload.clear();
        let r = module.read(i, &mut payload).await;
        let now = Instant::now().as_millis();
        if !schedule.due(r.value, r.status, now, r.deadband, settings.period_ms) || !conn.can_publish(qos) {
            continue;
        }
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
