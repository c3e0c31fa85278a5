//! The discovery / configuration protocol, PC side (UDP).

use std::net::{Ipv4Addr, SocketAddr};
use std::str::FromStr;
use std::time::{Duration, Instant};

use remodaq_protocol::access::{AllowList, Network};
use remodaq_protocol::auth;
use remodaq_protocol::discovery::{
    self, client, decode_challenge, decode_info, decode_reply, encode_request, info_flags, op, Reply, Request, Status,
    MAX_DATAGRAM,
};
use remodaq_protocol::net::NetConfig;
use serde::Serialize;
use tokio::net::UdpSocket;

use crate::ifaces::{self, Iface};
use crate::Error;

mod route;
use route::{datagram, is_broadcast, receive, Route};

/// A MAC address, written `02:ab:cd:ef:01:23`.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Debug)]
pub struct Mac(pub [u8; 6]);

impl FromStr for Mac {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let parts: Vec<&str> = s.split([':', '-']).collect();
        let bytes: Result<Vec<u8>, _> = parts.iter().map(|p| u8::from_str_radix(p, 16)).collect();
        match bytes {
            Ok(b) if b.len() == 6 && parts.iter().all(|p| p.len() == 2) => {
                Ok(Mac([b[0], b[1], b[2], b[3], b[4], b[5]]))
            }
            _ => Err(format!("`{s}` is not a MAC address (like 02:ab:cd:ef:01:23)")),
        }
    }
}

impl std::fmt::Display for Mac {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let m = self.0;
        write!(f, "{:02x}:{:02x}:{:02x}:{:02x}:{:02x}:{:02x}", m[0], m[1], m[2], m[3], m[4], m[5])
    }
}

/// Network settings as shown to people and scripts.
#[derive(Serialize, Clone, Copy, PartialEq, Eq, Debug)]
pub struct Net {
    pub ip: Ipv4Addr,
    pub mask: Ipv4Addr,
    pub gateway: Ipv4Addr,
    pub port: u16,
}

impl From<NetConfig> for Net {
    fn from(n: NetConfig) -> Self {
        Self { ip: n.ip.into(), mask: n.mask.into(), gateway: n.gateway.into(), port: n.port }
    }
}

/// A module that answered a search.
#[derive(Serialize, Clone, Debug)]
pub struct Found {
    pub model: String,
    pub name: String,
    pub firmware: String,
    pub mac: String,
    /// The settings in force.
    pub running: Net,
    /// The settings stored; different from `running` until the module restarts.
    pub stored: Net,
    pub uptime_s: u32,
    /// The Modbus/TCP port in force.
    #[serde(skip)]
    pub modbus_port: u16,
    /// Whether the module's Modbus write allow-list restricts writes (`null`: the module does
    /// not say).
    pub writes_restricted: Option<bool>,
    /// The factory password is in force (anyone on the LAN may change the network settings).
    pub factory_password: bool,
    /// The fingerprint of the key the module verifies firmware images with.
    pub update_key: String,
    /// The interface of this PC the module answered on (`name (address)`): `null` for a search
    /// sent to one module's address.
    pub interface: Option<String>,
}

/// Most modules one search lists.
pub const MAX_FOUND: usize = 1024;

/// A module-supplied string made safe to print: control characters (escape sequences of a
/// terminal among them) shown as `?`, at most 64 characters.
pub fn sanitize(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).chars().take(64).map(|c| if c.is_control() { '?' } else { c }).collect()
}

async fn socket() -> Result<UdpSocket, Error> {
    let socket =
        UdpSocket::bind("0.0.0.0:0").await.map_err(|e| Error::Other(format!("cannot open a UDP socket: {e}")))?;
    socket.set_broadcast(true).map_err(|e| Error::Other(format!("cannot enable broadcast: {e}")))?;
    Ok(socket)
}

/// A request id that differs between runs, so replies to an earlier run are ignored.
fn request_id() -> u16 {
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
    (std::process::id() as u16) ^ (nanos >> 8) as u16
}

/// The sockets a datagram to `to` leaves by, with their interface: for the broadcast address,
/// one per IPv4 interface that is up (those `only` names), or, on a PC with none but loopback,
/// one unbound socket as before; for one module's address, one socket on `only`'s interface, or
/// unbound (the PC's routes choose).
async fn vias(to: SocketAddr, only: Option<&str>) -> Result<Vec<(Option<Iface>, UdpSocket)>, Error> {
    let interfaces = match (is_broadcast(to), only) {
        (_, Some(only)) => ifaces::list(Some(only))?,
        (true, None) => ifaces::list(None)?,
        (false, None) => vec![],
    };
    if interfaces.is_empty() {
        return Ok(vec![(None, socket().await?)]);
    }
    // An interface whose socket cannot be made (an address going away, a duplicate one) is
    // said and left out; the others are searched.
    let mut sockets = Vec::new();
    let mut first_error = None;
    for iface in interfaces {
        match ifaces::socket(&iface) {
            Ok(socket) => sockets.push((Some(iface), socket)),
            Err(e) => {
                eprintln!("warning: {e}");
                first_error.get_or_insert(e);
            }
        }
    }
    match (sockets.is_empty(), first_error) {
        (true, Some(e)) => Err(e),
        _ => Ok(sockets),
    }
}

/// A module's answer to a search, on an interface.
pub struct Answer {
    pub mac: [u8; 6],
    pub found: Found,
    /// Where the answer came from: the address the module was reached at, which a PC tool
    /// talks to (Modbus, updates), never the unauthenticated `found.running.ip` the answer
    /// reports (security review finding 3).
    pub from: SocketAddr,
}

/// Sends `request` (search id `id`) by `socket` and collects the INFO answers until
/// `deadline` (the module `want` counted even beyond [`MAX_FOUND`]).
async fn collect(
    socket: UdpSocket,
    interface: Option<String>,
    to: SocketAddr,
    request: Vec<u8>,
    id: u16,
    deadline: Instant,
    want: Option<[u8; 6]>,
) -> Result<Vec<Answer>, Error> {
    let on = interface.as_deref().map_or(String::new(), |i| format!(" on {i}"));
    socket.send_to(&request, to).await.map_err(|e| Error::Other(format!("cannot send to {to}{on}: {e}")))?;
    let mut answers = Vec::new();
    let mut seen = std::collections::HashSet::new();
    let mut rx = [0u8; 512];
    while let Ok(received) = tokio::time::timeout_at(deadline.into(), socket.recv_from(&mut rx)).await {
        let Some((n, from)) = datagram(received) else { continue };
        let Some(info) = decode_info(&rx[..n]) else { continue };
        // Each module once (a set, not a scan of the list), and at most MAX_FOUND of them: a
        // flood of forged answers cannot grow the list without bound (nor hide `want`).
        let room = answers.len() < MAX_FOUND || want == Some(info.mac);
        if info.id != id || !room || !seen.insert(info.mac) {
            continue;
        }
        answers.push(Answer {
            from,
            mac: info.mac,
            found: Found {
                model: format!("{:04X}", info.model),
                name: sanitize(info.name),
                firmware: format!("{:04X}", info.version),
                mac: Mac(info.mac).to_string(),
                running: info.running.into(),
                stored: info.stored.into(),
                uptime_s: info.uptime_s,
                modbus_port: info.running.port,
                writes_restricted: Some(info.flags & info_flags::WRITES_RESTRICTED != 0),
                factory_password: info.flags & info_flags::FACTORY_PASSWORD != 0,
                update_key: info.update_key.iter().map(|b| format!("{b:02x}")).collect(),
                interface: interface.clone(),
            },
        });
    }
    Ok(answers)
}

/// Sends a search to `to` (on every interface for the broadcast address, or on `only`) and
/// collects INFO answers for `timeout`, each module once (by MAC, under the first interface,
/// in the system's order, it answered on).
pub async fn find(to: SocketAddr, only: Option<&str>, timeout: Duration) -> Result<Vec<Found>, Error> {
    let (by_interface, _) = search_each(to, only, timeout, None).await?;
    Ok(merge(by_interface))
}

/// The answers on each interface searched (in the system's order), and the interfaces. An
/// interface that could not send is said (stderr) and has no answers; an error only when none
/// could.
pub async fn search_each(
    to: SocketAddr,
    only: Option<&str>,
    timeout: Duration,
    want: Option<[u8; 6]>,
) -> Result<(Vec<Vec<Answer>>, Vec<Option<Iface>>), Error> {
    let id = request_id();
    let mut buf = [0u8; MAX_DATAGRAM];
    let n = encode_request(id, &Request::Search, &mut buf).unwrap_or(0);
    let deadline = Instant::now() + timeout;
    let mut tasks = tokio::task::JoinSet::new();
    let mut interfaces = Vec::new();
    for (i, (iface, socket)) in vias(to, only).await?.into_iter().enumerate() {
        let label = iface.as_ref().map(Iface::label);
        interfaces.push(iface);
        let request = buf[..n].to_vec();
        tasks.spawn(async move { (i, collect(socket, label, to, request, id, deadline, want).await) });
    }
    let mut by_interface: Vec<Vec<Answer>> = interfaces.iter().map(|_| Vec::new()).collect();
    let mut failures = Vec::new();
    while let Some(done) = tasks.join_next().await {
        match done {
            Ok((i, Ok(answers))) => by_interface[i] = answers,
            Ok((_, Err(e))) => {
                eprintln!("warning: {e}");
                failures.push(e);
            }
            Err(e) => failures.push(Error::Other(format!("the search failed: {e}"))),
        }
    }
    if !failures.is_empty() && failures.len() == interfaces.len() {
        return Err(failures.remove(0));
    }
    Ok((by_interface, interfaces))
}

/// Each module once, by MAC, under the first interface it answered on; at most [`MAX_FOUND`].
pub fn merge(by_interface: Vec<Vec<Answer>>) -> Vec<Found> {
    let mut seen = std::collections::HashSet::new();
    by_interface.into_iter().flatten().filter(|a| seen.insert(a.mac)).take(MAX_FOUND).map(|a| a.found).collect()
}

/// The route of a command for `mac` (security review finding 4): for one module's address,
/// that address, by [`vias`]'s socket. For the broadcast address, the module is searched for
/// on every interface (or `only`): the command goes by the interface it answered on, unicast to
/// the address its answer came from, so that no proof is broadcast and only that address's
/// answers are taken; by broadcast only when that address is not in the interface's subnet (a
/// module on a foreign subnet, which the PC cannot reach otherwise), which [`Outcome`] then
/// says. Asked twice, for a lost datagram; refused as [`route::choose`] says. `--interface`
/// then says which.
async fn via(to: SocketAddr, mac: Mac, only: Option<&str>, timeout: Duration) -> Result<Route, Error> {
    if !is_broadcast(to) {
        let mut sockets = vias(to, only).await?;
        return Ok(Route { socket: sockets.remove(0).1, target: to });
    }
    for _ in 0..2 {
        let (by_interface, interfaces) = search_each(to, only, timeout, Some(mac.0)).await?;
        let on: Vec<(Option<Iface>, Vec<SocketAddr>)> = by_interface
            .iter()
            .zip(interfaces)
            .map(|(answers, iface)| (iface, answers.iter().filter(|a| a.mac == mac.0).map(|a| a.from).collect()))
            .filter(|(_, from): &(_, Vec<SocketAddr>)| !from.is_empty())
            .collect();
        let Some((iface, target)) = route::choose(to, &mac.to_string(), &on)? else { continue };
        let socket = match &iface {
            Some(iface) => ifaces::socket(iface)?,
            None => socket().await?,
        };
        return Ok(Route { socket, target });
    }
    Err(Error::Timeout(format!(
        "module {mac} did not answer a search on any interface of this PC within {:.1} s (asked twice)",
        timeout.as_secs_f64()
    )))
}

/// The settings `remodaq net set` stores: all of them, from the command line (never taken from
/// an unauthenticated search answer).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NetChange {
    pub ip: Ipv4Addr,
    pub mask: Ipv4Addr,
    pub gateway: Ipv4Addr,
    pub port: u16,
}

/// A configuration command (the password is the login's).
pub enum Command<'a> {
    /// Store network settings.
    SetNetwork(NetConfig),
    /// Restart.
    Restart,
    /// Identify (no password).
    Identify,
    /// Change the password to this one.
    SetPassword(&'a str),
    /// Read the Modbus write allow-list.
    GetAccess,
    /// Store a Modbus write allow-list.
    SetAccess(AllowList),
}

/// Stores network settings on the module `mac` (in force after a restart); checked here first.
pub async fn set_network(
    to: SocketAddr,
    only: Option<&str>,
    mac: Mac,
    password: &str,
    change: NetChange,
    timeout: Duration,
) -> Result<Outcome, Error> {
    let net = NetConfig {
        ip: change.ip.octets(),
        mask: change.mask.octets(),
        gateway: change.gateway.octets(),
        port: change.port,
    };
    if !net.is_valid() {
        return Err(Error::Other("these settings are not usable (mask, address or port)".into()));
    }
    command(to, only, mac, Some(password), Command::SetNetwork(net), timeout).await
}

/// What a module did with new network settings.
pub const SET_NETWORK_DONE: &str = "network settings stored (in force after a restart)";

/// What a configuration command did.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// The module's allow-list, for [`Command::GetAccess`] (and what it stored for a set).
    pub list: Option<AllowList>,
    /// The factory password is in force on the module.
    pub factory_password: bool,
    /// The module is on another subnet than the PC's interface, so the command went by
    /// broadcast (its proof visible to every host on the segment): say so.
    pub broadcast: bool,
}

impl Command<'_> {
    /// What the module did, in words, when the command succeeded.
    pub fn done(&self) -> &'static str {
        match self {
            Command::SetNetwork(..) => SET_NETWORK_DONE,
            Command::Restart => "restarting",
            Command::Identify => "identifying: the LED blinks for 10 s",
            Command::SetPassword(..) => "password changed",
            Command::GetAccess => "",
            Command::SetAccess(list) if list.is_empty() => "Modbus writes allowed from any client",
            Command::SetAccess(..) => "Modbus writes allowed from the listed networks only",
        }
    }
}

/// Sends a configuration command to the module `mac` (by the interface it answers on) and
/// waits for its signed answer.
pub async fn command(
    to: SocketAddr,
    only: Option<&str>,
    mac: Mac,
    password: Option<&str>,
    cmd: Command<'_>,
    timeout: Duration,
) -> Result<Outcome, Error> {
    let route = via(to, mac, only, timeout).await?;
    let (reply, factory_password) = exchange(&route, mac, password, &cmd, timeout).await?;
    Ok(Outcome { list: reply.list, factory_password, broadcast: route.is_broadcast() })
}

/// What `remodaq` says of a module whose factory password is in force.
pub fn factory_warning(mac: Mac) -> String {
    format!(
        "warning: {mac} still has the factory password: anyone on the LAN can change its network \
         settings. Set one: remodaq password --mac {mac}"
    )
}

/// What the tools say when a command went by broadcast (a module on another subnet than the
/// PC's interface: [`Outcome::broadcast`]).
pub fn broadcast_note(mac: Mac) -> String {
    format!(
        "note: {mac} is on another subnet than this PC: the command went by broadcast, so every host on \
         the segment saw it (its proof of the password among it); give this PC an address in the \
         module's subnet to talk to it directly"
    )
}

/// A network in CIDR form.
pub fn cidr(n: Network) -> String {
    n.to_string()
}

/// Parses `a.b.c.d/n` (a bare address is /32).
pub fn parse_cidr(s: &str) -> Result<Network, String> {
    s.parse().map_err(|()| format!("`{s}` is not an IPv4 network (a.b.c.d/n, n from 0 to 32)"))
}

/// PBKDF2 iterations of a new password (the module accepts 4096 to 10 000 000).
pub const NEW_ITERATIONS: u32 = 100_000;

/// Random bytes from the OS.
pub fn random<const N: usize>() -> Result<[u8; N], Error> {
    let mut out = [0u8; N];
    getrandom::fill(&mut out).map_err(|e| Error::Other(format!("no random numbers from the OS: {e}")))?;
    Ok(out)
}

/// The keys of `password` for a module's salt and iteration count (a forged answer cannot make
/// this PC hash for hours: the count is bounded).
pub fn login(password: &str, salt: &[u8; 16], iterations: u32) -> Result<([u8; 32], auth::Credential), Error> {
    if !(auth::MIN_ITERATIONS..=auth::MAX_ITERATIONS).contains(&iterations) {
        return Err(Error::Reply(format!("the module asks for {iterations} PBKDF2 iterations: not a RemoDAQ module")));
    }
    Ok(auth::derive(password.as_bytes(), salt, iterations))
}

/// [`login`] on tokio's blocking threads: up to 10 million PBKDF2 iterations (a module, or a
/// forged answer, chooses them) must not stall the other work of the runtime (a window's polls).
pub async fn login_blocking(
    password: &str,
    salt: &[u8; 16],
    iterations: u32,
) -> Result<([u8; 32], auth::Credential), Error> {
    let (password, salt) = (password.to_string(), *salt);
    tokio::task::spawn_blocking(move || login(&password, &salt, iterations))
        .await
        .map_err(|e| Error::Other(format!("the key derivation failed: {e}")))?
}

/// Sends a configuration command (after a challenge, with a proof of `password`) and waits for
/// the module's signed reply (an error unless it is Ok). Also says whether the factory
/// password is in force.
async fn exchange(
    route: &Route,
    mac: Mac,
    password: Option<&str>,
    cmd: &Command<'_>,
    timeout: Duration,
) -> Result<(Reply, bool), Error> {
    let deadline = Instant::now() + timeout;
    let to = route.target;
    let silent = || format!("module {mac} did not answer at {to} within {:.1} s", timeout.as_secs_f64());
    let send = |bytes: Vec<u8>| async move {
        route.socket.send_to(&bytes, to).await.map_err(|e| Error::Other(format!("cannot send to {to}: {e}")))
    };
    let mut buf = [0u8; MAX_DATAGRAM];
    if let Command::Identify = cmd {
        let id = request_id();
        let n = encode_request(id, &Request::Identify { mac: mac.0 }, &mut buf).unwrap_or(0);
        send(buf[..n].to_vec()).await?;
        let reply = receive(route, deadline, silent, |d| {
            decode_reply(d).filter(|r| r.opcode == op::IDENTIFY && r.id == id && r.mac == mac.0)
        })
        .await?;
        return status(reply, mac).map(|r| (r, false));
    }
    let password = password.ok_or_else(|| Error::Other("a password is needed".into()))?;
    // A nonce the module used or forgot (another PC asked for many) is asked for once more.
    for attempt in 0..2 {
        let (id, cnonce) = (request_id(), random::<16>()?);
        let n = encode_request(id, &Request::Challenge { mac: mac.0, cnonce }, &mut buf).unwrap_or(0);
        send(buf[..n].to_vec()).await?;
        let challenge = receive(route, deadline, silent, |d| {
            decode_challenge(d).filter(|c| c.id == id && c.mac == mac.0 && c.cnonce == cnonce)
        })
        .await?;
        let (client_key, credential) = login_blocking(password, &challenge.salt, challenge.iterations).await?;
        let command = match *cmd {
            Command::SetNetwork(net) => discovery::Command::SetNetwork(net),
            Command::Restart => discovery::Command::Restart,
            Command::GetAccess => discovery::Command::GetAccess,
            Command::SetAccess(list) => discovery::Command::SetAccess(list),
            Command::SetPassword(new) => {
                let (_, new) = auth::derive(new.as_bytes(), &random::<16>()?, NEW_ITERATIONS);
                client::seal_credential(&new, &random::<32>()?, &challenge, &cnonce)
            }
            Command::Identify => return Err(Error::Other("identify needs no password".into())),
        };
        let id = request_id().wrapping_add(1);
        let request = Request::Command {
            mac: mac.0,
            auth: discovery::Auth { cnonce, snonce: challenge.snonce, proof: [0; 32] },
            command,
        };
        let n = encode_request(id, &request, &mut buf).ok_or_else(|| Error::Other("request too long".into()))?;
        client::prove(&mut buf[..n], &client_key);
        let request = buf[..n].to_vec();
        send(request.clone()).await?;
        let (reply, bytes) = receive(route, deadline, silent, |d| {
            decode_reply(d)
                .filter(|r| r.opcode == command.opcode() && r.id == id && r.mac == mac.0)
                .map(|r| (r, d.to_vec()))
        })
        .await?;
        if reply.signature.is_some() && !client::answer_is_genuine(&request, &bytes, &credential.server_key) {
            return Err(Error::Reply(format!(
                "{mac}: the answer is not signed by the module (a forged answer?); nothing is known to have changed"
            )));
        }
        if reply.status == Status::StaleNonce && attempt == 0 {
            continue;
        }
        let factory = challenge.flags & info_flags::FACTORY_PASSWORD != 0;
        return status(reply, mac).map(|r| (r, factory));
    }
    Err(Error::Other(format!("{mac}: the module kept refusing its own nonces")))
}

/// A reply's status as a result.
fn status(reply: Reply, mac: Mac) -> Result<Reply, Error> {
    let message = match reply.status {
        Status::Ok => return Ok(reply),
        Status::WrongPassword => return Err(Error::Refused(format!("{mac}: wrong password, nothing changed"))),
        Status::RateLimited => {
            return Err(Error::Refused(format!(
                "{mac}: too many wrong passwords on this module, try again in a minute"
            )));
        }
        Status::StaleNonce => return Err(Error::Refused(format!("{mac}: the module's nonce was already used"))),
        Status::SetPasswordFirst => {
            return Err(Error::Refused(format!(
                "{mac}: the factory password is in force: set a password first (remodaq password --mac {mac})"
            )));
        }
        Status::Invalid => "the module refused the settings (mask, address, port or password)",
        Status::StoreFailed => "the module could not store the settings",
        Status::CommitBudget => {
            return Err(Error::Refused(format!(
                "{mac}: too many settings changes, nothing changed: the module takes one more every 15 minutes (flash wear)"
            )));
        }
        Status::BadSignature | Status::Downgrade => "the module answered a status of the update service",
    };
    Err(Error::Other(format!("{mac}: {message}")))
}
