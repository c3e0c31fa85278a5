//! The network discovery and configuration protocol (UDP, port [`PORT`]); see
//! `docs/discovery.md` for the wire format. This module is the codec and the module side's
//! logic, without sockets: [`decode_request`] is pure and total (fuzzed), [`Service::handle`]
//! turns one datagram into at most one reply and an effect for the board.

use crate::module::{CommonSettings, SettingsAccess};
use crate::net::NetConfig;
use crate::password::{self, Check, Limiter, PasswordHash};

/// The UDP port modules listen on.
pub const PORT: u16 = 8300;
/// Datagrams longer than this are ignored.
pub const MAX_DATAGRAM: usize = 160;
/// First bytes of every datagram.
pub const MAGIC: [u8; 4] = *b"RDAQ";
/// Protocol version.
pub const VERSION: u8 = 1;
/// Header length: magic, version, opcode, request id.
pub const HEADER: usize = 8;

/// Request opcodes (replies set bit 7).
pub mod op {
    /// Who is there? Every module answers [`INFO`].
    pub const SEARCH: u8 = 0x01;
    /// Store new network settings (in force after a restart).
    pub const SET_NETWORK: u8 = 0x02;
    /// Restart.
    pub const RESTART: u8 = 0x03;
    /// Blink the identify LED for 10 s.
    pub const IDENTIFY: u8 = 0x04;
    /// Change the configuration password.
    pub const SET_PASSWORD: u8 = 0x05;
    /// Reply to SEARCH.
    pub const INFO: u8 = 0x81;
    /// Reply bit.
    pub const REPLY: u8 = 0x80;
}

/// Result codes of the configuration commands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Status {
    /// Done.
    Ok = 0,
    /// Wrong password: nothing changed.
    WrongPassword = 1,
    /// Too many wrong passwords: not checked, try later.
    RateLimited = 2,
    /// The settings are not usable (mask, address, port, password length).
    Invalid = 3,
    /// The settings could not be stored.
    StoreFailed = 4,
}

impl Status {
    /// The status of a code.
    pub fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            0 => Status::Ok,
            1 => Status::WrongPassword,
            2 => Status::RateLimited,
            3 => Status::Invalid,
            4 => Status::StoreFailed,
            _ => return None,
        })
    }
}

/// A decoded request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Request<'a> {
    /// SEARCH.
    Search,
    /// SET_NETWORK for the module with `mac`.
    SetNetwork {
        /// Target module.
        mac: [u8; 6],
        /// Configuration password.
        password: &'a [u8],
        /// New settings.
        net: NetConfig,
    },
    /// RESTART the module with `mac`.
    Restart {
        /// Target module.
        mac: [u8; 6],
        /// Configuration password.
        password: &'a [u8],
    },
    /// IDENTIFY the module with `mac`.
    Identify {
        /// Target module.
        mac: [u8; 6],
    },
    /// SET_PASSWORD of the module with `mac`.
    SetPassword {
        /// Target module.
        mac: [u8; 6],
        /// Current password.
        password: &'a [u8],
        /// New password.
        new: &'a [u8],
    },
}

/// A reader over a datagram that fails (None) instead of running past its end.
struct Reader<'a> {
    rest: &'a [u8],
}

impl<'a> Reader<'a> {
    fn bytes(&mut self, n: usize) -> Option<&'a [u8]> {
        if self.rest.len() < n {
            return None;
        }
        let (head, tail) = self.rest.split_at(n);
        self.rest = tail;
        Some(head)
    }
    fn array<const N: usize>(&mut self) -> Option<[u8; N]> {
        self.bytes(N)?.try_into().ok()
    }
    fn u16(&mut self) -> Option<u16> {
        self.array().map(u16::from_be_bytes)
    }
    fn string(&mut self) -> Option<&'a [u8]> {
        let [len] = self.array::<1>()?;
        let len = usize::from(len);
        if len > password::MAX_LEN {
            return None;
        }
        self.bytes(len)
    }
    fn net(&mut self) -> Option<NetConfig> {
        Some(NetConfig { ip: self.array()?, mask: self.array()?, gateway: self.array()?, port: self.u16()? })
    }
    fn end(&self) -> Option<()> {
        self.rest.is_empty().then_some(())
    }
}

/// The request id and request of a datagram; `None` for anything malformed, truncated,
/// oversized, of another version, or a reply.
pub fn decode_request(datagram: &[u8]) -> Option<(u16, Request<'_>)> {
    if datagram.len() > MAX_DATAGRAM {
        return None;
    }
    let mut r = Reader { rest: datagram };
    if r.array::<4>()? != MAGIC || r.array::<1>()? != [VERSION] {
        return None;
    }
    let [opcode] = r.array::<1>()?;
    let id = r.u16()?;
    let request = match opcode {
        op::SEARCH => Request::Search,
        op::SET_NETWORK => Request::SetNetwork { mac: r.array()?, password: r.string()?, net: r.net()? },
        op::RESTART => Request::Restart { mac: r.array()?, password: r.string()? },
        op::IDENTIFY => Request::Identify { mac: r.array()? },
        op::SET_PASSWORD => Request::SetPassword { mac: r.array()?, password: r.string()?, new: r.string()? },
        _ => return None,
    };
    r.end()?;
    Some((id, request))
}

/// Builds datagrams into a buffer (requests on the PC side, replies on the module side).
pub struct Writer<'a> {
    buf: &'a mut [u8],
    len: usize,
    overflow: bool,
}

impl<'a> Writer<'a> {
    /// Starts a datagram with its header.
    pub fn new(buf: &'a mut [u8], opcode: u8, id: u16) -> Self {
        let mut w = Self { buf, len: 0, overflow: false };
        w.bytes(&MAGIC);
        w.bytes(&[VERSION, opcode]);
        w.bytes(&id.to_be_bytes());
        w
    }
    /// Appends bytes.
    pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
        match self.buf.get_mut(self.len..self.len + b.len()) {
            Some(dst) => {
                dst.copy_from_slice(b);
                self.len += b.len();
            }
            None => self.overflow = true,
        }
        self
    }
    /// Appends a length-prefixed string (at most 255 bytes).
    pub fn string(&mut self, s: &[u8]) -> &mut Self {
        let n = s.len().min(255);
        self.bytes(&[n as u8]).bytes(&s[..n])
    }
    /// Appends network settings.
    pub fn net(&mut self, n: &NetConfig) -> &mut Self {
        self.bytes(&n.ip).bytes(&n.mask).bytes(&n.gateway).bytes(&n.port.to_be_bytes())
    }
    /// The datagram's length; `None` if it did not fit.
    pub fn finish(&self) -> Option<usize> {
        (!self.overflow).then_some(self.len)
    }
}

/// What a module says about itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Identity {
    /// Module name register value (8318h, 8350h).
    pub model: u16,
    /// Model string.
    pub name: &'static str,
    /// Firmware version register value.
    pub version: u16,
    /// MAC address.
    pub mac: [u8; 6],
    /// The network settings in force since start-up.
    pub running: NetConfig,
}

/// What the board must do after sending the reply.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Effect {
    /// Nothing.
    None,
    /// Restart the module (new network settings take effect).
    Restart,
    /// Blink the identify LED for 10 s.
    Identify,
}

/// The module side of the protocol.
pub struct Service {
    identity: Identity,
    limiter: Limiter,
}

impl Service {
    /// The service of a module.
    pub fn new(identity: Identity) -> Self {
        Self { identity, limiter: Limiter::default() }
    }

    /// Handles one datagram at `now_ms` (ms since start): the reply's length in `out` (none for
    /// datagrams that are ignored or addressed to another module) and the effect to carry out
    /// after sending it.
    pub async fn handle<A: SettingsAccess>(
        &mut self,
        datagram: &[u8],
        now_ms: u64,
        access: &mut A,
        out: &mut [u8],
    ) -> Option<(usize, Effect)> {
        let (id, request) = decode_request(datagram)?;
        let me = self.identity.mac;
        let (opcode, mac, password) = match request {
            Request::Search => return self.info(id, now_ms, access.settings(), out).map(|n| (n, Effect::None)),
            Request::Identify { mac } if mac == me => {
                return result(out, op::IDENTIFY, id, me, Status::Ok).map(|n| (n, Effect::Identify));
            }
            Request::SetNetwork { mac, password, .. } => (op::SET_NETWORK, mac, password),
            Request::Restart { mac, password } => (op::RESTART, mac, password),
            Request::SetPassword { mac, password, .. } => (op::SET_PASSWORD, mac, password),
            Request::Identify { .. } => return None,
        };
        if mac != me {
            return None;
        }
        let current = *access.settings();
        let status = match self.limiter.check(&current.password(), password, now_ms) {
            Check::Locked => Status::RateLimited,
            Check::Wrong => Status::WrongPassword,
            Check::Ok => match request {
                Request::SetNetwork { net, .. } if net.is_valid() => {
                    let mut s = current;
                    s.set_net(net);
                    commit(access, s).await
                }
                Request::SetPassword { new, .. } if (password::MIN_LEN..=password::MAX_LEN).contains(&new.len()) => {
                    let mut s = current;
                    s.set_password(PasswordHash::new(current.password().next_salt(&me, now_ms), new));
                    commit(access, s).await
                }
                Request::Restart { .. } => Status::Ok,
                _ => Status::Invalid,
            },
        };
        let effect = if opcode == op::RESTART && status == Status::Ok { Effect::Restart } else { Effect::None };
        if status == Status::WrongPassword {
            crate::warn!("discovery: wrong configuration password");
        }
        result(out, opcode, id, me, status).map(|n| (n, effect))
    }

    fn info<S: CommonSettings>(&self, id: u16, now_ms: u64, settings: &S, out: &mut [u8]) -> Option<usize> {
        let i = &self.identity;
        let mut w = Writer::new(out, op::INFO, id);
        w.bytes(&i.model.to_be_bytes()).bytes(&i.version.to_be_bytes()).bytes(&i.mac);
        w.net(&i.running).net(&settings.net());
        w.bytes(&((now_ms / 1000) as u32).to_be_bytes()).string(i.name.as_bytes());
        w.finish()
    }
}

async fn commit<A: SettingsAccess>(access: &mut A, settings: A::Settings) -> Status {
    match access.commit(settings).await {
        Ok(()) => Status::Ok,
        Err(_) => Status::StoreFailed,
    }
}

fn result(out: &mut [u8], opcode: u8, id: u16, mac: [u8; 6], status: Status) -> Option<usize> {
    let mut w = Writer::new(out, opcode | op::REPLY, id);
    w.bytes(&mac).bytes(&[status as u8]);
    w.finish()
}

/// A decoded INFO reply (the PC side).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Info<'a> {
    /// Request id echoed.
    pub id: u16,
    /// Module name register value.
    pub model: u16,
    /// Firmware version.
    pub version: u16,
    /// MAC address.
    pub mac: [u8; 6],
    /// Settings in force.
    pub running: NetConfig,
    /// Settings stored (in force after a restart).
    pub stored: NetConfig,
    /// Seconds since start-up.
    pub uptime_s: u32,
    /// Model string.
    pub name: &'a [u8],
}

/// Decodes an INFO reply.
pub fn decode_info(datagram: &[u8]) -> Option<Info<'_>> {
    let mut r = Reader { rest: datagram };
    if r.array::<4>()? != MAGIC || r.array::<1>()? != [VERSION] || r.array::<1>()? != [op::INFO] {
        return None;
    }
    let info = Info {
        id: r.u16()?,
        model: r.u16()?,
        version: r.u16()?,
        mac: r.array()?,
        running: r.net()?,
        stored: r.net()?,
        uptime_s: u32::from_be_bytes(r.array()?),
        name: r.string()?,
    };
    r.end()?;
    Some(info)
}

/// Decodes a command reply: (opcode without the reply bit, id, mac, status).
pub fn decode_result(datagram: &[u8]) -> Option<(u8, u16, [u8; 6], Status)> {
    let mut r = Reader { rest: datagram };
    if r.array::<4>()? != MAGIC || r.array::<1>()? != [VERSION] {
        return None;
    }
    let [opcode] = r.array::<1>()?;
    if opcode & op::REPLY == 0 || opcode == op::INFO {
        return None;
    }
    let (id, mac, [status]) = (r.u16()?, r.array()?, r.array::<1>()?);
    r.end()?;
    Some((opcode & !op::REPLY, id, mac, Status::from_code(status)?))
}

/// A UDP socket as the service needs it (embassy-net on the target, std on the host).
#[allow(async_fn_in_trait)]
pub trait Datagrams {
    /// A socket error.
    type Error: crate::fmt::Loggable;
    /// Receives one datagram: its length, source address and port. A datagram longer than the
    /// buffer may be truncated; the buffer is one byte longer than [`MAX_DATAGRAM`], so the
    /// decoder still sees that it is oversized.
    async fn recv(&mut self, buf: &mut [u8]) -> Result<(usize, [u8; 4], u16), Self::Error>;
    /// Sends one datagram.
    async fn send(&mut self, buf: &[u8], ip: [u8; 4], port: u16) -> Result<(), Self::Error>;
}

/// Serves the protocol forever. Replies go to the requester, or to the broadcast address (same
/// port) when the requester is outside the module's subnet, so a PC can configure a module
/// whose settings do not fit its network. `effect` runs after each reply is sent.
pub async fn serve<R, A, D>(
    socket: &mut D,
    map: &embassy_sync::mutex::Mutex<R, A>,
    identity: Identity,
    mut effect: impl AsyncFnMut(Effect),
) -> !
where
    R: embassy_sync::blocking_mutex::raw::RawMutex,
    A: SettingsAccess,
    D: Datagrams,
{
    let mut service = Service::new(identity);
    let mut rx = [0u8; MAX_DATAGRAM + 1];
    let mut tx = [0u8; MAX_DATAGRAM];
    loop {
        let (n, ip, port) = match socket.recv(&mut rx).await {
            Ok(received) => received,
            Err(e) => {
                crate::warn!("discovery: receive failed: {:?}", e);
                continue;
            }
        };
        let now_ms = embassy_time::Instant::now().as_millis();
        let reply = {
            let mut map = map.lock().await;
            service.handle(&rx[..n], now_ms, &mut *map, &mut tx).await
        };
        let Some((len, what)) = reply else { continue };
        let to = if identity.running.same_subnet(ip) { ip } else { [255; 4] };
        if let Err(e) = socket.send(&tx[..len], to, port).await {
            crate::warn!("discovery: send failed: {:?}", e);
        }
        effect(what).await;
    }
}
