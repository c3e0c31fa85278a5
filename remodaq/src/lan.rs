//! The discovery / configuration protocol, PC side (UDP).

use std::net::{Ipv4Addr, SocketAddr};
use std::str::FromStr;
use std::time::{Duration, Instant};

use remodaq_protocol::access::{AllowList, Network};
use remodaq_protocol::discovery::{
    decode_info, decode_reply, encode_request, info_flags, Reply, Request, Status, MAX_DATAGRAM,
};
use remodaq_protocol::net::NetConfig;
use serde::Serialize;
use tokio::net::UdpSocket;

use crate::Error;

/// The length of a received datagram; `None` for a receive error, which ends nothing: on
/// Windows an ICMP "port unreachable" for an earlier datagram (WSAECONNRESET) or an oversized
/// datagram (WSAEMSGSIZE) surface as errors of the next receive, and other modules may still
/// answer before the deadline.
fn datagram(received: std::io::Result<(usize, SocketAddr)>) -> Option<usize> {
    received.ok().map(|(n, _)| n)
}

/// A MAC address, written `02:ab:cd:ef:01:23`.
#[derive(Clone, Copy, PartialEq, Eq)]
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
#[derive(Serialize, Clone, Copy, PartialEq)]
pub struct Net {
    ip: Ipv4Addr,
    mask: Ipv4Addr,
    gateway: Ipv4Addr,
    port: u16,
}

impl From<NetConfig> for Net {
    fn from(n: NetConfig) -> Self {
        Self { ip: n.ip.into(), mask: n.mask.into(), gateway: n.gateway.into(), port: n.port }
    }
}

/// A module that answered a search.
#[derive(Serialize)]
pub struct Found {
    model: String,
    name: String,
    firmware: String,
    mac: String,
    /// The settings in force.
    running: Net,
    /// The settings stored; different from `running` until the module restarts.
    stored: Net,
    uptime_s: u32,
    /// The Modbus/TCP port in force.
    #[serde(skip)]
    pub modbus_port: u16,
    /// Whether the module's Modbus write allow-list restricts writes (`null`: the module does
    /// not say).
    pub writes_restricted: Option<bool>,
    #[serde(skip)]
    raw_stored: NetConfig,
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

/// Sends a search to `to` and collects INFO answers for `timeout`.
pub async fn find(to: SocketAddr, timeout: Duration) -> Result<Vec<Found>, Error> {
    let socket = socket().await?;
    let id = request_id();
    let mut buf = [0u8; MAX_DATAGRAM];
    let n = encode_request(id, &Request::Search, &mut buf).unwrap_or(0);
    socket.send_to(&buf[..n], to).await.map_err(|e| Error::Other(format!("cannot send to {to}: {e}")))?;
    let deadline = Instant::now() + timeout;
    let mut found: Vec<Found> = Vec::new();
    let mut rx = [0u8; 512];
    while let Ok(received) = tokio::time::timeout_at(deadline.into(), socket.recv_from(&mut rx)).await {
        let Some(n) = datagram(received) else { continue };
        let Some(info) = decode_info(&rx[..n]) else { continue };
        if info.id != id || found.iter().any(|f| f.mac == Mac(info.mac).to_string()) {
            continue;
        }
        found.push(Found {
            model: format!("{:04X}", info.model),
            name: String::from_utf8_lossy(info.name).into_owned(),
            firmware: format!("{:04X}", info.version),
            mac: Mac(info.mac).to_string(),
            running: info.running.into(),
            stored: info.stored.into(),
            uptime_s: info.uptime_s,
            modbus_port: info.running.port,
            writes_restricted: info.flags.map(|f| f & info_flags::WRITES_RESTRICTED != 0),
            raw_stored: info.stored,
        });
    }
    Ok(found)
}

/// `remodaq search`.
pub async fn search(to: SocketAddr, timeout: Duration, json: bool) -> Result<(), Error> {
    let found = find(to, timeout).await?;
    if json {
        println!("{}", serde_json::to_string_pretty(&found).unwrap_or_default());
        return Ok(());
    }
    if found.is_empty() {
        println!("no module answered within {:.1} s", timeout.as_secs_f64());
        return Ok(());
    }
    println!(
        "{:<14} {:<18} {:<16} {:<16} {:<16} {:>6} {:>9}",
        "model", "mac", "ip", "mask", "gateway", "port", "uptime"
    );
    for f in &found {
        let r = f.running;
        println!(
            "{:<14} {:<18} {:<16} {:<16} {:<16} {:>6} {:>8}s",
            f.name, f.mac, r.ip, r.mask, r.gateway, r.port, f.uptime_s
        );
        if f.stored != f.running {
            let s = f.stored;
            println!(
                "{:<14} {:<18} {:<16} {:<16} {:<16} {:>6}   (stored: after a restart)",
                "", "", s.ip, s.mask, s.gateway, s.port
            );
        }
    }
    Ok(())
}

/// The settings `remodaq net set` changes; `None` keeps the stored value.
pub struct NetChange {
    pub ip: Option<Ipv4Addr>,
    pub mask: Option<Ipv4Addr>,
    pub gateway: Option<Ipv4Addr>,
    pub port: Option<u16>,
}

/// A configuration command.
pub enum Command<'a> {
    /// Store network settings.
    SetNetwork(&'a str, NetConfig),
    /// Restart.
    Restart(&'a str),
    /// Identify.
    Identify,
    /// Change the password (old, new).
    SetPassword(&'a str, &'a str),
    /// Read the Modbus write allow-list.
    GetAccess(&'a str),
    /// Store a Modbus write allow-list.
    SetAccess(&'a str, AllowList),
}

/// `remodaq net set`: the stored settings (found by a search) with the changes applied.
pub async fn set_network(
    to: SocketAddr,
    mac: Mac,
    password: &str,
    change: NetChange,
    timeout: Duration,
    json: bool,
) -> Result<(), Error> {
    let found = find(to, timeout).await?;
    let module = found
        .iter()
        .find(|f| f.mac == mac.to_string())
        .ok_or_else(|| Error::Timeout(format!("no module with MAC {mac} answered at {to}")))?;
    let s = module.raw_stored;
    let net = NetConfig {
        ip: change.ip.map_or(s.ip, |a| a.octets()),
        mask: change.mask.map_or(s.mask, |a| a.octets()),
        gateway: change.gateway.map_or(s.gateway, |a| a.octets()),
        port: change.port.unwrap_or(s.port),
    };
    if !net.is_valid() {
        return Err(Error::Other("these settings are not usable (mask, address or port)".into()));
    }
    command(to, mac, Command::SetNetwork(password, net), timeout, json).await
}

/// Sends a configuration command and prints its result.
pub async fn command(to: SocketAddr, mac: Mac, cmd: Command<'_>, timeout: Duration, json: bool) -> Result<(), Error> {
    let what = match cmd {
        Command::SetNetwork(..) => "network settings stored (in force after a restart)",
        Command::Restart(_) => "restarting",
        Command::Identify => "identifying: the LED blinks for 10 s",
        Command::SetPassword(..) => "password changed",
        Command::GetAccess(_) => "",
        Command::SetAccess(_, list) if list.is_empty() => "Modbus writes allowed from any client",
        Command::SetAccess(..) => "Modbus writes allowed from the listed networks only",
    };
    let reply = exchange(to, mac, &cmd, timeout).await?;
    if let Some(list) = reply.list {
        let nets: Vec<String> = list.iter().map(cidr).collect();
        if json {
            let out = serde_json::json!({ "mac": mac.to_string(), "restricted": !list.is_empty(), "allow": nets });
            println!("{out}");
        } else if nets.is_empty() {
            println!("{mac}: Modbus writes allowed from any client (allow-list empty)");
        } else {
            println!("{mac}: Modbus writes allowed only from {}", nets.join(", "));
        }
    } else if json {
        println!("{}", serde_json::json!({ "mac": mac.to_string(), "status": "ok", "message": what }));
    } else {
        println!("{mac}: {what}");
    }
    Ok(())
}

/// A network in CIDR form.
pub fn cidr(n: Network) -> String {
    format!("{}/{}", Ipv4Addr::from(n.ip), n.prefix)
}

/// Parses `a.b.c.d/n` (a bare address is /32).
pub fn parse_cidr(s: &str) -> Result<Network, String> {
    let (ip, prefix) = s.split_once('/').unwrap_or((s, "32"));
    let ip: Ipv4Addr = ip.parse().map_err(|_| format!("`{s}` is not an IPv4 network (a.b.c.d/n)"))?;
    let prefix: u8 = prefix.parse().map_err(|_| format!("`{s}`: the prefix is 0 to 32"))?;
    Network::new(ip.octets(), prefix).ok_or_else(|| format!("`{s}`: the prefix is 0 to 32"))
}

/// Sends a configuration command and waits for the module's reply (an error unless it is Ok).
async fn exchange(to: SocketAddr, mac: Mac, cmd: &Command<'_>, timeout: Duration) -> Result<Reply, Error> {
    let socket = socket().await?;
    let id = request_id();
    let mut buf = [0u8; MAX_DATAGRAM];
    let mac_bytes = mac.0;
    let request = match *cmd {
        Command::SetNetwork(password, net) => {
            Request::SetNetwork { mac: mac_bytes, password: password.as_bytes(), net }
        }
        Command::Restart(password) => Request::Restart { mac: mac_bytes, password: password.as_bytes() },
        Command::Identify => Request::Identify { mac: mac_bytes },
        Command::SetPassword(old, new) => {
            Request::SetPassword { mac: mac_bytes, password: old.as_bytes(), new: new.as_bytes() }
        }
        Command::GetAccess(password) => Request::GetAccess { mac: mac_bytes, password: password.as_bytes() },
        Command::SetAccess(password, list) => {
            Request::SetAccess { mac: mac_bytes, password: password.as_bytes(), list }
        }
    };
    let n = encode_request(id, &request, &mut buf).ok_or_else(|| Error::Other("password too long".into()))?;
    socket.send_to(&buf[..n], to).await.map_err(|e| Error::Other(format!("cannot send to {to}: {e}")))?;
    let deadline = Instant::now() + timeout;
    let mut rx = [0u8; 512];
    loop {
        let received = tokio::time::timeout_at(deadline.into(), socket.recv_from(&mut rx)).await;
        let Ok(received) = received else {
            return Err(Error::Timeout(format!(
                "module {mac} did not answer at {to} within {:.1} s",
                timeout.as_secs_f64()
            )));
        };
        let Some(n) = datagram(received) else { continue };
        let Some(reply) = decode_reply(&rx[..n]) else { continue };
        if reply.opcode != request.opcode() || reply.id != id || reply.mac != mac.0 {
            continue;
        }
        let message = match reply.status {
            Status::Ok => return Ok(reply),
            Status::WrongPassword => return Err(Error::Refused(format!("{mac}: wrong password, nothing changed"))),
            Status::RateLimited => {
                return Err(Error::Refused(format!("{mac}: too many wrong passwords, try again later")));
            }
            Status::Invalid => "the module refused the settings (mask, address, port or password length)",
            Status::StoreFailed => "the module could not store the settings",
            Status::BadSignature => "the module answered a status of the update service (bad signature)",
        };
        return Err(Error::Other(format!("{mac}: {message}")));
    }
}
