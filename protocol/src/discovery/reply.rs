//! The reply side: the module's INFO reply, CHALLENGE answer and command replies, their
//! decoding on the PC and the encoding of a CHALLENGE answer.

use super::wire::{op, Reader, Writer};
use crate::access::AllowList;
use crate::auth::{KEY_LEN, NONCE_LEN, SALT_LEN};
use crate::net::NetConfig;
use crate::status::Status;

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
    /// Model string (untrusted bytes: sanitise before showing them).
    pub name: &'a [u8],
    /// Flags ([`info_flags`]).
    pub flags: u8,
    /// The first 8 bytes of the SHA-256 of the public key the module verifies firmware images
    /// with.
    pub update_key: [u8; 8],
}

/// Flags of an INFO reply and a CHALLENGE answer.
pub mod info_flags {
    /// The Modbus write allow-list is not empty: writes are restricted (extensions §4).
    pub const WRITES_RESTRICTED: u8 = 1 << 0;
    /// The factory password is in force: set one (`remodaq password`).
    pub const FACTORY_PASSWORD: u8 = 1 << 1;
}

/// Decodes an INFO reply.
pub fn decode_info(datagram: &[u8]) -> Option<Info<'_>> {
    let mut r = Reader { rest: datagram };
    let (opcode, id) = r.header()?;
    if opcode != op::INFO {
        return None;
    }
    let info = Info {
        id,
        model: r.u16()?,
        version: r.u16()?,
        mac: r.array()?,
        running: r.net()?,
        stored: r.net()?,
        uptime_s: r.u32()?,
        name: r.string()?,
        flags: r.array::<1>()?[0],
        update_key: r.array()?,
    };
    r.end()?;
    Some(info)
}

/// A decoded CHALLENGE answer (the PC side).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Challenge {
    /// Request id echoed.
    pub id: u16,
    /// The module's MAC address.
    pub mac: [u8; 6],
    /// The PC's nonce, echoed.
    pub cnonce: [u8; NONCE_LEN],
    /// The module's nonce: single use, valid for `crate::discovery` [`NONCE_LIFETIME_S`].
    pub snonce: [u8; NONCE_LEN],
    /// The PBKDF2 salt of the module's password.
    pub salt: [u8; SALT_LEN],
    /// Its PBKDF2 iterations.
    pub iterations: u32,
    /// The module's X25519 key for sealing a new credential.
    pub public: [u8; KEY_LEN],
    /// [`info_flags`].
    pub flags: u8,
}

/// Seconds a nonce of the module stays valid.
pub const NONCE_LIFETIME_S: u64 = 30;

/// Encodes a CHALLENGE answer (the module side).
pub fn encode_challenge(c: &Challenge, out: &mut [u8]) -> Option<usize> {
    let mut w = Writer::new(out, op::CHALLENGE | op::REPLY, c.id);
    w.bytes(&c.mac).bytes(&c.cnonce).bytes(&c.snonce).bytes(&c.salt);
    w.bytes(&c.iterations.to_be_bytes()).bytes(&c.public).bytes(&[c.flags]);
    w.finish()
}

/// Decodes a CHALLENGE answer.
pub fn decode_challenge(datagram: &[u8]) -> Option<Challenge> {
    let mut r = Reader { rest: datagram };
    let (opcode, id) = r.header()?;
    if opcode != op::CHALLENGE | op::REPLY {
        return None;
    }
    let c = Challenge {
        id,
        mac: r.array()?,
        cnonce: r.array()?,
        snonce: r.array()?,
        salt: r.array()?,
        iterations: r.u32()?,
        public: r.array()?,
        flags: r.array::<1>()?[0],
    };
    r.end()?;
    Some(c)
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
    /// The module's signature, on an answer given after a right proof
    /// ([`Status::after_proof`]).
    pub signature: Option<[u8; KEY_LEN]>,
}

/// Decodes a command reply. A GET_ACCESS reply with [`Status::Ok`] carries the allow-list;
/// every reply after a right proof ends with the module's signature.
pub fn decode_reply(datagram: &[u8]) -> Option<Reply> {
    let mut r = Reader { rest: datagram };
    let (opcode, id) = r.header()?;
    if opcode & op::REPLY == 0 || opcode == op::INFO || opcode == op::CHALLENGE | op::REPLY {
        return None;
    }
    let (mac, [status]) = (r.array()?, r.array::<1>()?);
    let (opcode, status) = (opcode & !op::REPLY, Status::from_code(status)?);
    let signature = match opcode != op::IDENTIFY && status.after_proof() {
        true => {
            let at = r.rest.len().checked_sub(KEY_LEN)?;
            let (body, signature) = r.rest.split_at(at);
            r.rest = body;
            Some(signature.try_into().ok()?)
        }
        false => None,
    };
    let list = match (opcode, status) {
        (op::GET_ACCESS, Status::Ok) => Some(r.allow_list()?),
        _ => None,
    };
    r.end()?;
    Some(Reply { opcode, id, mac, status, list, signature })
}
