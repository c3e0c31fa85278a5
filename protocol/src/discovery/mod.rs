//! The network discovery and configuration protocol (UDP, port [`PORT`]), the codec only; see
//! `docs/discovery.md` for the wire format and `docs/security.md` for its authentication.
//! [`decode_request`] is pure and total (fuzzed); the module side's service is in
//! `remodaq-shared`, the PC side in the `remodaq` utility ([`client`], with the `client`
//! feature).
//!
//! Commands that change or reveal settings are authenticated ([`Auth`], `crate::auth`): no
//! password crosses the wire, each proof is bound to a single-use nonce of the module and to
//! every byte of its request, and the module signs its answer.

use crate::access::{AllowList, ENCODED_MAX};
use crate::auth::{CREDENTIAL_LEN, KEY_LEN, NONCE_LEN, SALT_LEN};
use crate::net::NetConfig;

mod reply;
mod request;

pub use reply::{
    decode_challenge, decode_info, decode_reply, encode_challenge, info_flags, Challenge, Info, Reply, NONCE_LIFETIME_S,
};
pub use request::{auth_message, decode_request, encode_request, Auth, Command, Request};

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
/// Label of the AuthMessage of a configuration command.
pub const CLIENT_LABEL: &[u8] = b"RDAQ discovery v2 request";
/// Label of the module's signature over a command and its answer.
pub const SERVER_LABEL: &[u8] = b"RDAQ discovery v2 answer";
/// Label of the key that seals a new credential.
pub const SEAL_LABEL: &[u8] = b"RDAQ new credential";

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

/// Result codes of the configuration commands (and of the update session).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Status {
    /// Done.
    Ok = 0,
    /// The proof does not match the module's password: nothing changed.
    WrongPassword = 1,
    /// The module-wide guessing budget is spent: not checked, try later.
    RateLimited = 2,
    /// The settings are not usable (mask, address, port, credential), or an image is not for
    /// this module.
    Invalid = 3,
    /// The settings (or the update) could not be stored.
    StoreFailed = 4,
    /// Firmware update only: the image's signature does not match its header and firmware, or
    /// was not made with this module's key. Nothing changed.
    BadSignature = 5,
    /// The nonce is not one the module handed out, was used already or expired: nothing was
    /// checked; ask for a new challenge.
    StaleNonce = 6,
    /// The factory password is still in force: set a password first (firmware updates and
    /// allow-list changes are refused until then).
    SetPasswordFirst = 7,
    /// Firmware update only: the image's security counter is below the module's (an older
    /// release, anti-rollback). Nothing changed.
    Downgrade = 8,
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
            6 => Status::StaleNonce,
            7 => Status::SetPasswordFirst,
            8 => Status::Downgrade,
            _ => return None,
        })
    }

    /// Whether the module answers this status only after a right proof: such an answer
    /// carries the module's signature.
    pub fn after_proof(self) -> bool {
        !matches!(self, Status::WrongPassword | Status::RateLimited | Status::StaleNonce)
    }
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
    fn u32(&mut self) -> Option<u32> {
        self.array().map(u32::from_be_bytes)
    }
    fn string(&mut self) -> Option<&'a [u8]> {
        let [len] = self.array::<1>()?;
        self.bytes(usize::from(len))
    }
    fn net(&mut self) -> Option<NetConfig> {
        Some(NetConfig { ip: self.array()?, mask: self.array()?, gateway: self.array()?, port: self.u16()? })
    }
    fn allow_list(&mut self) -> Option<AllowList> {
        let list = AllowList::decode(self.rest)?;
        self.rest = &[];
        Some(list)
    }
    fn auth(&mut self) -> Option<Auth> {
        Some(Auth { cnonce: self.array()?, snonce: self.array()?, proof: self.array()? })
    }
    fn end(&self) -> Option<()> {
        self.rest.is_empty().then_some(())
    }
    /// The header of this protocol version: its opcode and request id.
    fn header(&mut self) -> Option<(u8, u16)> {
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

/// The PC side of authentication: proofs and the check of the module's signature.
#[cfg(any(feature = "client", test))]
pub mod client {
    use super::*;
    use crate::auth;

    /// Fills in the proof of an encoded authenticated request (`ClientKey` from
    /// `crate::auth::derive`); false if it is too short to be one.
    pub fn prove(datagram: &mut [u8], client_key: &[u8; KEY_LEN]) -> bool {
        let Some(parts) = auth_message(datagram) else { return false };
        let proof = auth::client_proof(client_key, &parts);
        datagram[PROOF_AT..PROOF_AT + KEY_LEN].copy_from_slice(&proof);
        true
    }

    /// Whether `reply` (a datagram) carries the module's right signature over `request` and
    /// itself: the module that knows the password answered this very request.
    pub fn answer_is_genuine(request: &[u8], reply: &[u8], server_key: &[u8; KEY_LEN]) -> bool {
        let (Some(parts), Some(at)) = (auth_message(request), reply.len().checked_sub(KEY_LEN)) else {
            return false;
        };
        let (body, signature) = reply.split_at(at);
        let expected = auth::server_signature(server_key, &[SERVER_LABEL, parts[1], parts[2], body]);
        signature.try_into().is_ok_and(|s| auth::same(&expected, s))
    }

    /// The new credential of SET_PASSWORD sealed for the module: the PC's ephemeral secret
    /// `secret`, the module's key-agreement key and both nonces from the challenge. Returns the
    /// command.
    pub fn seal_credential(
        new: &auth::Credential,
        secret: &[u8; KEY_LEN],
        challenge: &Challenge,
        cnonce: &[u8; NONCE_LEN],
    ) -> Command {
        let public = auth::x25519(secret, &auth::BASE_POINT);
        let shared = auth::x25519(secret, &challenge.public);
        let mut sealed = new.encode();
        auth::seal(&shared, &[SEAL_LABEL, cnonce, &challenge.snonce], &mut sealed);
        Command::SetPassword { public, sealed }
    }

    /// What a PC asks of a module in [`transact`].
    #[derive(Clone, Copy, Debug)]
    pub enum Ask<'a> {
        /// Store network settings.
        SetNetwork(NetConfig),
        /// Restart.
        Restart,
        /// Read the allow-list.
        GetAccess,
        /// Store an allow-list.
        SetAccess(AllowList),
        /// Change the password to `new`, with this salt, iteration count and ephemeral X25519
        /// secret (the caller's random numbers).
        SetPassword {
            /// The new password.
            new: &'a [u8],
            /// Its salt.
            salt: [u8; SALT_LEN],
            /// Its PBKDF2 iterations.
            iterations: u32,
            /// The PC's ephemeral X25519 secret.
            secret: [u8; KEY_LEN],
        },
    }

    /// Why [`transact`] has no answer.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum Failure {
        /// No (fitting) answer.
        NoAnswer,
        /// An answer after a proof without the module's right signature.
        Forged,
        /// The challenge asks for an iteration count out of range.
        Iterations,
    }

    /// One authenticated command, the whole exchange: a challenge, the command with its proof
    /// of `password`, the answer checked. `send` sends a datagram and returns the module's
    /// answer to it (the caller matches ids and MACs). Returns the answer and the request sent
    /// (to replay it in tests).
    pub fn transact(
        mac: [u8; 6],
        password: &[u8],
        ask: Ask<'_>,
        cnonce: [u8; NONCE_LEN],
        id: u16,
        mut send: impl FnMut(&[u8]) -> Option<std::vec::Vec<u8>>,
    ) -> Result<(Reply, std::vec::Vec<u8>), Failure> {
        let mut buf = [0u8; MAX_DATAGRAM];
        let n = encode_request(id, &Request::Challenge { mac, cnonce }, &mut buf).ok_or(Failure::NoAnswer)?;
        let answer = send(&buf[..n]).ok_or(Failure::NoAnswer)?;
        let challenge = decode_challenge(&answer).filter(|c| c.cnonce == cnonce).ok_or(Failure::NoAnswer)?;
        if !(auth::MIN_ITERATIONS..=auth::MAX_ITERATIONS).contains(&challenge.iterations) {
            return Err(Failure::Iterations);
        }
        let (client_key, credential) = auth::derive(password, &challenge.salt, challenge.iterations);
        let command = match ask {
            Ask::SetNetwork(net) => Command::SetNetwork(net),
            Ask::Restart => Command::Restart,
            Ask::GetAccess => Command::GetAccess,
            Ask::SetAccess(list) => Command::SetAccess(list),
            Ask::SetPassword { new, salt, iterations, secret } => {
                let (_, new) = auth::derive(new, &salt, iterations);
                seal_credential(&new, &secret, &challenge, &cnonce)
            }
        };
        let request =
            Request::Command { mac, auth: Auth { cnonce, snonce: challenge.snonce, proof: [0; KEY_LEN] }, command };
        let id = id.wrapping_add(1);
        let n = encode_request(id, &request, &mut buf).ok_or(Failure::NoAnswer)?;
        prove(&mut buf[..n], &client_key);
        let answer = send(&buf[..n]).ok_or(Failure::NoAnswer)?;
        let reply =
            decode_reply(&answer).filter(|r| r.id == id && r.opcode == command.opcode()).ok_or(Failure::NoAnswer)?;
        if reply.signature.is_some() && !answer_is_genuine(&buf[..n], &answer, &credential.server_key) {
            return Err(Failure::Forged);
        }
        Ok((reply, buf[..n].to_vec()))
    }
}
