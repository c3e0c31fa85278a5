//! The network discovery and configuration protocol (UDP, port [`PORT`]), the codec only; see
//! `docs/discovery.md` for the wire format. [`decode_request`] is pure and total (fuzzed); the
//! module side's service is in `remodaq-shared`, the PC side in the `remodaq` utility.

use crate::access::{AllowList, ENCODED_MAX};
use crate::net::NetConfig;

/// The longest password (bytes).
pub const MAX_PASSWORD_LEN: usize = 32;

/// The UDP port modules listen on.
pub const PORT: u16 = 8300;
/// Datagrams longer than this are ignored.
pub const MAX_DATAGRAM: usize = 160;
/// First bytes of every datagram.
pub const MAGIC: [u8; 4] = *b"RDAQ";
/// Protocol version.
pub const VERSION: u8 = 1;

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
    /// Read the Modbus write allow-list (extensions §4); the reply carries it.
    pub const GET_ACCESS: u8 = 0x06;
    /// Store a new Modbus write allow-list (in force at once).
    pub const SET_ACCESS: u8 = 0x07;
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
    /// The settings (or the update) could not be stored.
    StoreFailed = 4,
    /// Firmware update only: the image's signature does not match its firmware, or was not
    /// made with this module's key. Nothing changed.
    BadSignature = 5,
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
            5 => Status::BadSignature,
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
    /// GET_ACCESS of the module with `mac`.
    GetAccess {
        /// Target module.
        mac: [u8; 6],
        /// Configuration password.
        password: &'a [u8],
    },
    /// SET_ACCESS of the module with `mac`.
    SetAccess {
        /// Target module.
        mac: [u8; 6],
        /// Configuration password.
        password: &'a [u8],
        /// The new list (empty: writes not restricted).
        list: AllowList,
    },
}

impl Request<'_> {
    /// The request's opcode.
    pub fn opcode(&self) -> u8 {
        match self {
            Request::Search => op::SEARCH,
            Request::SetNetwork { .. } => op::SET_NETWORK,
            Request::Restart { .. } => op::RESTART,
            Request::Identify { .. } => op::IDENTIFY,
            Request::SetPassword { .. } => op::SET_PASSWORD,
            Request::GetAccess { .. } => op::GET_ACCESS,
            Request::SetAccess { .. } => op::SET_ACCESS,
        }
    }
}

/// Encodes request `id` into `out`; `None` if it does not fit (a password over
/// [`MAX_PASSWORD_LEN`] bytes is not encodable either).
pub fn encode_request(id: u16, request: &Request<'_>, out: &mut [u8]) -> Option<usize> {
    let mut w = Writer::new(out, request.opcode(), id);
    let password = |w: &mut Writer<'_>, p: &[u8]| {
        if p.len() > MAX_PASSWORD_LEN {
            w.overflow = true;
        }
        w.string(p);
    };
    match *request {
        Request::Search => {}
        Request::SetNetwork { mac, password: p, net } => {
            password(w.bytes(&mac), p);
            w.net(&net);
        }
        Request::Restart { mac, password: p } | Request::GetAccess { mac, password: p } => password(w.bytes(&mac), p),
        Request::Identify { mac } => {
            w.bytes(&mac);
        }
        Request::SetPassword { mac, password: p, new } => {
            password(w.bytes(&mac), p);
            password(&mut w, new);
        }
        Request::SetAccess { mac, password: p, list } => {
            password(w.bytes(&mac), p);
            w.allow_list(&list);
        }
    }
    w.finish()
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
        if len > MAX_PASSWORD_LEN {
            return None;
        }
        self.bytes(len)
    }
    fn net(&mut self) -> Option<NetConfig> {
        Some(NetConfig { ip: self.array()?, mask: self.array()?, gateway: self.array()?, port: self.u16()? })
    }
    fn allow_list(&mut self) -> Option<AllowList> {
        let list = AllowList::decode(self.rest)?;
        self.rest = &[];
        Some(list)
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
        op::GET_ACCESS => Request::GetAccess { mac: r.array()?, password: r.string()? },
        op::SET_ACCESS => Request::SetAccess { mac: r.array()?, password: r.string()?, list: r.allow_list()? },
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
    /// Appends an allow-list.
    pub fn allow_list(&mut self, list: &AllowList) -> &mut Self {
        let mut buf = [0u8; ENCODED_MAX];
        let n = list.encode(&mut buf);
        self.bytes(&buf[..n])
    }
    /// The datagram's length; `None` if it did not fit.
    pub fn finish(&self) -> Option<usize> {
        (!self.overflow).then_some(self.len)
    }
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
    /// Flags ([`info_flags`]); `None` from a module whose reply has none (older firmware).
    pub flags: Option<u8>,
}

/// Flags at the end of an INFO reply.
pub mod info_flags {
    /// The Modbus write allow-list is not empty: writes are restricted (extensions §4).
    pub const WRITES_RESTRICTED: u8 = 1 << 0;
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
        flags: match r.rest {
            [] => None,
            [flags] => Some(*flags),
            _ => return None,
        },
    };
    Some(info)
}

/// A decoded command reply (the PC side).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reply {
    /// The command's opcode (without the reply bit).
    pub opcode: u8,
    /// Request id echoed.
    pub id: u16,
    /// The module's MAC address.
    pub mac: [u8; 6],
    /// The result.
    pub status: Status,
    /// GET_ACCESS answered [`Status::Ok`]: the allow-list.
    pub list: Option<AllowList>,
}

/// Decodes a command reply. Only a GET_ACCESS reply with [`Status::Ok`] carries more than the
/// status: the allow-list.
pub fn decode_reply(datagram: &[u8]) -> Option<Reply> {
    let mut r = Reader { rest: datagram };
    if r.array::<4>()? != MAGIC || r.array::<1>()? != [VERSION] {
        return None;
    }
    let [opcode] = r.array::<1>()?;
    if opcode & op::REPLY == 0 || opcode == op::INFO {
        return None;
    }
    let (id, mac, [status]) = (r.u16()?, r.array()?, r.array::<1>()?);
    let (opcode, status) = (opcode & !op::REPLY, Status::from_code(status)?);
    let list = match (opcode, status) {
        (op::GET_ACCESS, Status::Ok) => Some(r.allow_list()?),
        _ => None,
    };
    r.end()?;
    Some(Reply { opcode, id, mac, status, list })
}
