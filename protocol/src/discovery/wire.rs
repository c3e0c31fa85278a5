//! The framing every datagram shares: the port, magic, version and header, the opcodes, the
//! labels of the authentication, and the reader and writer of datagrams.

use crate::access::{AllowList, ENCODED_MAX};
use crate::auth::NONCE_LEN;
use crate::net::NetConfig;

/// The UDP port modules listen on.
pub const PORT: u16 = 8300;
/// Datagrams longer than this are ignored.
pub const MAX_DATAGRAM: usize = 256;
/// First bytes of every datagram.
pub const MAGIC: [u8; 4] = *b"RDAQ";
/// Protocol version (2: authenticated commands; version 1 carried passwords and is ignored).
pub const VERSION: u8 = 2;
/// Bytes of the header: magic, version, opcode, request id.
pub const HEADER_LEN: usize = 8;
/// Where the proof of an authenticated request starts: header, MAC, both nonces.
pub const PROOF_AT: usize = HEADER_LEN + 6 + 2 * NONCE_LEN;
/// Domain tag of the AuthMessage of a configuration command (`crate::domain_tag!`).
pub const CLIENT_LABEL: &[u8] = crate::domain_tag!(b"RDAQ discovery v2 request");
/// Domain tag of the module's signature over a command and its answer.
pub const SERVER_LABEL: &[u8] = crate::domain_tag!(b"RDAQ discovery v2 answer");
/// Domain tag of the key that seals a new credential.
pub const SEAL_LABEL: &[u8] = crate::domain_tag!(b"RDAQ new credential");

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
    /// Change the configuration password (a sealed new credential).
    pub const SET_PASSWORD: u8 = 0x05;
    /// Read the Modbus write allow-list (extensions §4); the reply carries it.
    pub const GET_ACCESS: u8 = 0x06;
    /// Store a new Modbus write allow-list (in force at once).
    pub const SET_ACCESS: u8 = 0x07;
    /// Ask for a nonce (and the salt, iterations and the module's key-agreement key).
    pub const CHALLENGE: u8 = 0x08;
    /// Reply to SEARCH.
    pub const INFO: u8 = 0x81;
    /// Reply bit.
    pub const REPLY: u8 = 0x80;
}

/// A reader over a datagram that fails (None) instead of running past its end.
pub(super) struct Reader<'a> {
    pub(super) rest: &'a [u8],
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
    pub(super) fn array<const N: usize>(&mut self) -> Option<[u8; N]> {
        self.bytes(N)?.try_into().ok()
    }
    pub(super) fn u16(&mut self) -> Option<u16> {
        self.array().map(u16::from_be_bytes)
    }
    pub(super) fn u32(&mut self) -> Option<u32> {
        self.array().map(u32::from_be_bytes)
    }
    pub(super) fn string(&mut self) -> Option<&'a [u8]> {
        let [len] = self.array::<1>()?;
        self.bytes(usize::from(len))
    }
    pub(super) fn net(&mut self) -> Option<NetConfig> {
        Some(NetConfig { ip: self.array()?, mask: self.array()?, gateway: self.array()?, port: self.u16()? })
    }
    pub(super) fn allow_list(&mut self) -> Option<AllowList> {
        let list = AllowList::decode(self.rest)?;
        self.rest = &[];
        Some(list)
    }
    pub(super) fn end(&self) -> Option<()> {
        self.rest.is_empty().then_some(())
    }
    /// The header of this protocol version: its opcode and request id.
    pub(super) fn header(&mut self) -> Option<(u8, u16)> {
        if self.array::<4>()? != MAGIC || self.array::<1>()? != [VERSION] {
            return None;
        }
        let [opcode] = self.array::<1>()?;
        Some((opcode, self.u16()?))
    }
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
