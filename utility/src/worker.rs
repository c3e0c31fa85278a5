//! The network side of the utility: one thread with a tokio runtime that searches, polls the
//! modules and carries out the user's writes and commands. The window never waits on the
//! network: it sends [`Job`]s and takes the [`Event`]s that are ready at each frame, and the
//! worker asks for a frame when it has something new.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;
use std::sync::Arc;
use std::time::{Duration, Instant};

use remodaq_client::ifaces::Iface;
use remodaq_client::lan::{self, Found, Mac, NetChange};
use remodaq_client::modbus::Module;
use remodaq_client::reading::{read_analog, read_digital, Analog, Digital};
use remodaq_client::settings::{apply, Write};
use remodaq_client::update::{self, Progress};
use remodaq_client::Error;
use remodaq_protocol::access::AllowList;
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver, UnboundedSender};
use tokio::task::JoinHandle;
use zeroize::Zeroizing;

/// Where the times of readings and of the trend come from: the system's monotonic clock, or
/// (a test seam) a clock that stands still until the test moves it, so that a trend's points
/// fall at the same times in every run.
#[derive(Clone, Debug, Default)]
pub struct Clock(Option<Arc<(Instant, AtomicU64)>>);

impl Clock {
    /// A clock at its start until [`set`](Self::set) moves it.
    pub fn manual() -> Self {
        Self(Some(Arc::new((Instant::now(), AtomicU64::new(0)))))
    }

    pub fn now(&self) -> Instant {
        match &self.0 {
            None => Instant::now(),
            Some(c) => c.0 + Duration::from_micros(c.1.load(Ordering::SeqCst)),
        }
    }

    /// Moves a manual clock to `since_start` after its start (the system's: nothing).
    pub fn set(&self, since_start: Duration) {
        if let Some(c) = &self.0 {
            c.1.store(u64::try_from(since_start.as_micros()).unwrap_or(u64::MAX), Ordering::SeqCst);
        }
    }
}

/// A module found by a search, with where to reach it.
#[derive(Clone, Debug)]
pub struct Located {
    pub found: Found,
    pub mac: Mac,
    /// Where its configuration commands go (where the search that found it went).
    pub to: SocketAddr,
    /// The PC's interface it answered on (`None`: a search sent to its own address).
    pub iface: Option<Iface>,
    /// Its Modbus/TCP address.
    pub modbus: SocketAddr,
}

/// One reading of a module.
#[derive(Clone, Debug)]
pub enum Reading {
    Analog(Analog),
    Digital(Digital),
}

/// A configuration command (discovery protocol, with the password).
#[derive(Clone, Debug)]
pub enum Config {
    SetNetwork(NetChange),
    /// Restart, then search again until the module answers (by MAC).
    Restart,
    SetPassword(Zeroizing<String>),
    GetAccess,
    SetAccess(AllowList),
    /// MQTT's settings, through the web console at this address (docs/mqtt.md).
    GetMqtt(SocketAddr),
    /// MQTT's settings stored, with a CA certificate and credentials when given.
    SetMqtt(Box<MqttChange>),
}

/// MQTT's settings to store through the web console at `web`, the CA certificate (PEM) and the
/// broker's user name and password when given.
#[derive(Clone, Debug)]
pub struct MqttChange {
    pub web: SocketAddr,
    pub settings: remodaq_client::web::MqttSettings,
    pub ca: Option<String>,
    pub credentials: Option<(String, Zeroizing<String>)>,
}

/// What the window asks for.
pub enum Job {
    /// Search at these addresses (the broadcast address goes out on every interface, or on
    /// `only`).
    Search { at: Vec<SocketAddr>, only: Option<String> },
    /// Poll these modules, each at its interval (replaces the set polled before). A module
    /// marked `true` wakes the window with each reading (the one shown); the others only when
    /// they stop or start answering (the tree shows that), so that modules polled in the
    /// background cost the window no frames.
    Poll(Vec<(Located, Duration, bool)>),
    /// A Modbus write.
    Write { id: u64, modbus: SocketAddr, write: Write },
    /// A configuration command; `only`: the interface the user chose to search on (`None`:
    /// all, and a MAC that answers on more than one is refused, as the CLI does).
    Config {
        id: u64,
        module: Box<Located>,
        password: Zeroizing<String>,
        command: Config,
        search_at: Vec<SocketAddr>,
        only: Option<String>,
    },
    /// A firmware update.
    Update { id: u64, modbus: SocketAddr, mac: Mac, image: PathBuf, password: Zeroizing<String> },
}

/// What a finished job gives.
#[derive(Clone, Debug)]
pub enum Done {
    /// What the module did, in words.
    Said(String),
    /// The allow-list read or stored.
    Access(AllowList),
    /// The module restarted and answered again: what is in force now.
    Restarted(Option<Box<Located>>),
    /// Firmware before and after.
    Updated { before: u16, after: u16 },
    /// MQTT's settings as the module holds them (after a read, or a store).
    Mqtt(Box<remodaq_client::web::MqttSettings>),
}

/// What the worker tells the window.
pub enum Event {
    /// A search's result: the modules, and the interfaces searched.
    Searched(Result<(Vec<Located>, Vec<Iface>), Error>),
    /// A poll of the module with this MAC.
    Reading { mac: Mac, at: Instant, reading: Box<Result<Reading, Error>> },
    /// A job finished.
    Done { id: u64, result: Result<Done, Error> },
    /// How far an update got.
    Progress { id: u64, progress: Progress },
}

/// The handle the window keeps.
pub struct Worker {
    jobs: UnboundedSender<Job>,
    events: mpsc::Receiver<Event>,
}

type Wake = Arc<dyn Fn() + Send + Sync>;

impl Worker {
    /// Starts the worker thread; `wake` asks the window for a frame. `timeout` bounds every
    /// exchange with a module.
    /// `clock` times the readings.
    pub fn start(wake: impl Fn() + Send + Sync + 'static, timeout: Duration, clock: Clock) -> std::io::Result<Self> {
        let (jobs, rx) = unbounded_channel();
        let (tx, events) = mpsc::channel();
        let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
        let wake: Wake = Arc::new(wake);
        std::thread::Builder::new()
            .name("remodaq-network".into())
            .spawn(move || runtime.block_on(serve(rx, Out { tx, wake, clock }, timeout)))?;
        Ok(Self { jobs, events })
    }

    /// Queues a job (never blocks).
    pub fn send(&self, job: Job) {
        // The worker only stops with the program.
        let _ = self.jobs.send(job);
    }

    /// The events that are ready (never blocks).
    pub fn ready(&self) -> Vec<Event> {
        self.events.try_iter().collect()
    }
}

#[derive(Clone)]
struct Out {
    tx: mpsc::Sender<Event>,
    wake: Wake,
    clock: Clock,
}

impl Out {
    fn send(&self, e: Event) {
        let _ = self.tx.send(e);
        (self.wake)();
    }

    /// Queues an event for the window's next frame without asking for one.
    fn queue(&self, e: Event) {
        let _ = self.tx.send(e);
    }
}

async fn serve(mut jobs: UnboundedReceiver<Job>, out: Out, timeout: Duration) {
    // Writes one after the other, in the order the user made them (a pulse train before its
    // extra pulses), each on a connection of its own.
    let (writes, mut queue) = unbounded_channel::<(u64, SocketAddr, Write)>();
    let writer = out.clone();
    tokio::spawn(async move {
        while let Some((id, modbus, write)) = queue.recv().await {
            let result = async {
                let mut m = Module::connect(&modbus.to_string(), timeout).await?;
                apply(&mut m, &write).await.map(Done::Said)
            }
            .await;
            writer.send(Event::Done { id, result });
        }
    });
    let mut polls: HashMap<Mac, (SocketAddr, Duration, bool, JoinHandle<()>)> = HashMap::new();
    while let Some(job) = jobs.recv().await {
        match job {
            Job::Search { at, only } => {
                let out = out.clone();
                tokio::spawn(async move { out.send(Event::Searched(search(&at, only.as_deref(), timeout).await)) });
            }
            Job::Poll(list) => {
                // Keep a running poll whose module and interval are the same (its connection
                // with it).
                let mut keep = HashMap::new();
                for (module, every, wake) in list {
                    match polls.remove(&module.mac) {
                        Some((addr, was, woke, task)) if addr == module.modbus && was == every && woke == wake => {
                            keep.insert(module.mac, (addr, was, woke, task));
                        }
                        other => {
                            if let Some((_, _, _, task)) = other {
                                task.abort();
                            }
                            let task = tokio::spawn(poll(module.mac, module.modbus, every, wake, timeout, out.clone()));
                            keep.insert(module.mac, (module.modbus, every, wake, task));
                        }
                    }
                }
                for (_, (_, _, _, task)) in polls.drain() {
                    task.abort();
                }
                polls = keep;
            }
            Job::Write { id, modbus, write } => {
                let _ = writes.send((id, modbus, write));
            }
            Job::Config { id, module, password, command, search_at, only } => {
                let out = out.clone();
                tokio::spawn(async move {
                    let result = configure(&module, &password, command, &search_at, only.as_deref(), timeout).await;
                    out.send(Event::Done { id, result });
                });
            }
            Job::Update { id, modbus, mac, image, password } => {
                let out = out.clone();
                tokio::spawn(async move {
                    let progress = out.clone();
                    let result = update::update(
                        &modbus.to_string(),
                        Some(mac),
                        &image,
                        &password,
                        remodaq_protocol::update::PORT,
                        timeout,
                        move |p| progress.send(Event::Progress { id, progress: p }),
                    )
                    .await
                    .map(|u| Done::Updated { before: u.before, after: u.after });
                    out.send(Event::Done { id, result });
                });
            }
        }
    }
}

/// Searches at every address in `at`; each module once (by MAC).
pub async fn search(
    at: &[SocketAddr],
    only: Option<&str>,
    timeout: Duration,
) -> Result<(Vec<Located>, Vec<Iface>), Error> {
    let mut found: Vec<Located> = Vec::new();
    let mut interfaces = Vec::new();
    let mut error = None;
    for &to in at {
        match lan::search_each(to, only, timeout, None).await {
            Ok((by_interface, ifaces)) => {
                for (answers, iface) in by_interface.into_iter().zip(ifaces.iter()) {
                    for a in answers {
                        if found.iter().any(|f| f.mac.0 == a.mac) {
                            continue;
                        }
                        // Modbus (polls, writes, updates) goes to the address the module
                        // answered from, never to the unauthenticated address its INFO reports
                        // (security review finding 3): a forged answer naming another address
                        // cannot redirect them. A simulated module on this PC answers from
                        // loopback, where its Modbus server listens.
                        let modbus = SocketAddr::new(a.from.ip(), a.found.modbus_port);
                        found.push(Located { mac: Mac(a.mac), found: a.found, to, iface: iface.clone(), modbus });
                    }
                }
                interfaces.extend(ifaces.into_iter().flatten().filter(|i| !interfaces.contains(i)).collect::<Vec<_>>());
            }
            Err(e) => error = Some(e),
        }
    }
    match error {
        Some(e) if found.is_empty() && interfaces.is_empty() => Err(e),
        _ => Ok((found, interfaces)),
    }
}

/// Polls one module for ever: a reading every `every`, or the error (no answer) when it fails;
/// the connection is made again after a failure. Each reading wakes the window when `wake`,
/// else only a change between answering and not.
async fn poll(mac: Mac, addr: SocketAddr, every: Duration, wake: bool, timeout: Duration, out: Out) {
    let mut module: Option<Module> = None;
    let mut answered = None;
    let mut next = tokio::time::Instant::now();
    loop {
        let result = async {
            if module.is_none() {
                module = Some(Module::connect(&addr.to_string(), timeout).await?);
            }
            let Some(m) = module.as_mut() else { return Err(Error::Other("no connection".into())) };
            if m.model == remodaq_protocol::m8318::MODULE_NAME {
                read_analog(m).await.map(Reading::Analog)
            } else {
                // The latch and overflow flags only for the module shown (reading clears them).
                read_digital(m, wake).await.map(Reading::Digital)
            }
        }
        .await;
        if result.is_err() {
            module = None;
        }
        let changed = answered != Some(result.is_ok());
        answered = Some(result.is_ok());
        let event = Event::Reading { mac, at: out.clock.now(), reading: Box::new(result) };
        if wake || changed {
            out.send(event);
        } else {
            out.queue(event);
        }
        next += every;
        let now = tokio::time::Instant::now();
        if next < now {
            next = now;
        }
        tokio::time::sleep_until(next).await;
    }
}

/// Carries out a configuration command; a restart is followed by searches until the module
/// answers again (at most 30 s).
async fn configure(
    module: &Located,
    password: &str,
    command: Config,
    search_at: &[SocketAddr],
    only: Option<&str>,
    timeout: Duration,
) -> Result<Done, Error> {
    let cmd = match &command {
        Config::GetMqtt(web) => {
            let mut session = remodaq_client::web::Session::log_in(*web, password).await?;
            return Ok(Done::Mqtt(Box::new(session.mqtt().await?)));
        }
        Config::SetMqtt(change) => {
            let mut session = remodaq_client::web::Session::log_in(change.web, password).await?;
            session.set_mqtt(&change.settings).await?;
            if let Some(pem) = &change.ca {
                session.set_mqtt_ca(pem).await?;
            }
            if let Some((user, broker_password)) = &change.credentials {
                session.set_mqtt_credentials(user, broker_password).await?;
            }
            return Ok(Done::Mqtt(Box::new(session.mqtt().await?)));
        }
        Config::SetNetwork(change) => {
            let outcome = lan::set_network(module.to, only, module.mac, password, *change, timeout).await?;
            return Ok(Done::Said(said_with_route(lan::SET_NETWORK_DONE, module.mac, &outcome)));
        }
        Config::Restart => lan::Command::Restart,
        Config::SetPassword(new) => lan::Command::SetPassword(new),
        Config::GetAccess => lan::Command::GetAccess,
        Config::SetAccess(list) => lan::Command::SetAccess(*list),
    };
    let said = cmd.done();
    let outcome = lan::command(module.to, only, module.mac, Some(password), cmd, timeout).await?;
    match command {
        Config::Restart => {
            // The module answers, then restarts: search until it answers again, restarted (its
            // uptime no longer than the time since the command: not the old run's last answer).
            let started = Instant::now();
            tokio::time::sleep(Duration::from_millis(500)).await;
            while started.elapsed() < Duration::from_secs(30) {
                let at: Vec<SocketAddr> = if search_at.is_empty() { vec![module.to] } else { search_at.to_vec() };
                if let Ok((found, _)) = search(&at, only, timeout).await {
                    let restarted = |f: &Located| f64::from(f.found.uptime_s) <= started.elapsed().as_secs_f64() + 1.0;
                    if let Some(back) = found.into_iter().find(|f| f.mac == module.mac && restarted(f)) {
                        return Ok(Done::Restarted(Some(Box::new(back))));
                    }
                }
                tokio::time::sleep(Duration::from_millis(300)).await;
            }
            Ok(Done::Restarted(None))
        }
        Config::GetAccess => Ok(Done::Access(outcome.list.unwrap_or(AllowList::EMPTY))),
        // The module answers a store with its status only: what is in force is the list sent.
        Config::SetAccess(sent) => Ok(Done::Access(outcome.list.unwrap_or(sent))),
        _ => Ok(Done::Said(said_with_route(said, module.mac, &outcome))),
    }
}

/// What a command did, and, when it went by broadcast (a module on another subnet), that it did.
fn said_with_route(said: &str, mac: lan::Mac, outcome: &lan::Outcome) -> String {
    if outcome.broadcast {
        format!("{said}. {}", lan::broadcast_note(mac))
    } else {
        said.to_string()
    }
}

#[cfg(test)]
mod tests {
    use std::net::{Ipv4Addr, SocketAddr};
    use std::time::Duration;

    use remodaq_protocol::discovery::{decode_request, op, Request, Writer};
    use remodaq_protocol::net::NetConfig;

    /// Security review finding 3: a search answer reporting another address (here 10.9.8.7)
    /// does not redirect Modbus and updates: they go to the address the answer came from.
    #[test]
    fn modbus_goes_where_the_answer_came_from_not_where_it_says() {
        let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        runtime.block_on(async {
            let module = tokio::net::UdpSocket::bind((Ipv4Addr::LOCALHOST, 0)).await.unwrap();
            let at = module.local_addr().unwrap();
            let answer = tokio::spawn(async move {
                let mut rx = [0u8; 512];
                let (n, pc) = module.recv_from(&mut rx).await.unwrap();
                let Some((id, Request::Search)) = decode_request(&rx[..n]) else { panic!("not a search") };
                let claimed = NetConfig { ip: [10, 9, 8, 7], mask: [255, 0, 0, 0], gateway: [0; 4], port: 8123 };
                let mut tx = [0u8; 512];
                let mut w = Writer::new(&mut tx, op::INFO, id);
                w.bytes(&0x8350u16.to_be_bytes()).bytes(&0xA100u16.to_be_bytes()).bytes(&[2, 0, 0, 0, 0, 7]);
                w.net(&claimed).net(&claimed).bytes(&5u32.to_be_bytes()).string(b"ADAM-8350");
                w.bytes(&[0]).bytes(&[0; 8]);
                let len = w.finish().unwrap();
                module.send_to(&tx[..len], pc).await.unwrap();
            });
            let (found, _) = super::search(&[at], None, Duration::from_millis(500)).await.unwrap();
            answer.await.unwrap();
            assert_eq!(found.len(), 1);
            assert_eq!(found[0].found.running.ip, Ipv4Addr::new(10, 9, 8, 7), "what the answer claims");
            assert_eq!(found[0].modbus, SocketAddr::from((Ipv4Addr::LOCALHOST, 8123)), "where it came from");
        });
    }
}
