//! The request side: what a PC asks (the requests, their authentication block and commands),
//! its encoding, and the module's total decoding of a datagram into a request.

use super::wire::{op, Reader, Writer, CLIENT_LABEL, MAX_DATAGRAM, PROOF_AT};
use crate::access::AllowList;
use crate::auth::{KEY_LEN, NONCE_LEN, SEALED_LEN};
use crate::net::NetConfig;

/// The authentication block of a command: the PC's nonce, the module's nonce (from a
/// CHALLENGE answer), and the proof over every other byte of the request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Auth {
    /// The PC's nonce.
    pub cnonce: [u8; NONCE_LEN],
    /// The module's nonce.
    pub snonce: [u8; NONCE_LEN],
    /// ClientProof (`crate::auth::client_proof`); zeros while the request is being built.
    pub proof: [u8; KEY_LEN],
}

impl Reader<'_> {
    fn auth(&mut self) -> Option<Auth> {
        Some(Auth { cnonce: self.array()?, snonce: self.array()?, proof: self.array()? })
    }
}

/// What an authenticated request asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    /// SET_NETWORK: store these settings.
    SetNetwork(NetConfig),
    /// RESTART.
    Restart,
    /// SET_PASSWORD: the PC's ephemeral X25519 key, and the new credential sealed with the key
    /// agreed with the module's, with its key confirmation (`crate::auth::seal_credential`).
    SetPassword {
        /// The PC's ephemeral X25519 public key.
        public: [u8; KEY_LEN],
        /// The new credential, sealed.
        sealed: [u8; SEALED_LEN],
    },
    /// GET_ACCESS: read the allow-list.
    GetAccess,
    /// SET_ACCESS: store this allow-list (empty: writes not restricted).
    SetAccess(AllowList),
}

impl Command {
    /// The command's opcode.
    pub fn opcode(&self) -> u8 {
        match self {
            Command::SetNetwork(_) => op::SET_NETWORK,
            Command::Restart => op::RESTART,
            Command::SetPassword { .. } => op::SET_PASSWORD,
            Command::GetAccess => op::GET_ACCESS,
            Command::SetAccess(_) => op::SET_ACCESS,
        }
    }
}

/// A decoded request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Request {
    /// SEARCH.
    Search,
    /// IDENTIFY the module with `mac` (no authentication: it only blinks a LED).
    Identify {
        /// Target module.
        mac: [u8; 6],
    },
    /// CHALLENGE: the module with `mac` hands out a nonce.
    Challenge {
        /// Target module.
        mac: [u8; 6],
        /// The PC's nonce (echoed, so the PC matches the answer).
        cnonce: [u8; NONCE_LEN],
    },
    /// An authenticated command for the module with `mac`.
    Command {
        /// Target module.
        mac: [u8; 6],
        /// The authentication block.
        auth: Auth,
        /// What it asks for.
        command: Command,
    },
}

impl Request {
    /// The request's opcode.
    pub fn opcode(&self) -> u8 {
        match self {
            Request::Search => op::SEARCH,
            Request::Identify { .. } => op::IDENTIFY,
            Request::Challenge { .. } => op::CHALLENGE,
            Request::Command { command, .. } => command.opcode(),
        }
    }
}

/// Encodes request `id` into `out`; `None` if it does not fit. A command's proof is encoded as
/// given ([`client::prove`](super::client::prove) fills it in).
pub fn encode_request(id: u16, request: &Request, out: &mut [u8]) -> Option<usize> {
    let mut w = Writer::new(out, request.opcode(), id);
    match *request {
        Request::Search => {}
        Request::Identify { mac } => {
            w.bytes(&mac);
        }
        Request::Challenge { mac, cnonce } => {
            w.bytes(&mac).bytes(&cnonce);
        }
        Request::Command { mac, auth, command } => {
            w.bytes(&mac).bytes(&auth.cnonce).bytes(&auth.snonce).bytes(&auth.proof);
            match command {
                Command::SetNetwork(net) => {
                    w.net(&net);
                }
                Command::Restart | Command::GetAccess => {}
                Command::SetPassword { public, sealed } => {
                    w.bytes(&public).bytes(&sealed);
                }
                Command::SetAccess(list) => {
                    w.allow_list(&list);
                }
            }
        }
    }
    w.finish()
}

/// The AuthMessage of an authenticated request (every byte but the proof), in parts, after
/// [`CLIENT_LABEL`]; `None` if the datagram is too short to hold a proof.
pub fn auth_message(datagram: &[u8]) -> Option<[&[u8]; 3]> {
    let tail = datagram.get(PROOF_AT + KEY_LEN..)?;
    Some([CLIENT_LABEL, &datagram[..PROOF_AT], tail])
}

/// The request id and request of a datagram; `None` for anything malformed, truncated,
/// oversized, of another version, or a reply.
pub fn decode_request(datagram: &[u8]) -> Option<(u16, Request)> {
    if datagram.len() > MAX_DATAGRAM {
        return None;
    }
    let mut r = Reader { rest: datagram };
    let (opcode, id) = r.header()?;
    let request = match opcode {
        op::SEARCH => Request::Search,
        op::IDENTIFY => Request::Identify { mac: r.array()? },
        op::CHALLENGE => Request::Challenge { mac: r.array()?, cnonce: r.array()? },
        op::SET_NETWORK | op::RESTART | op::SET_PASSWORD | op::GET_ACCESS | op::SET_ACCESS => {
            let (mac, auth) = (r.array()?, r.auth()?);
            let command = match opcode {
                op::SET_NETWORK => Command::SetNetwork(r.net()?),
                op::RESTART => Command::Restart,
                op::SET_PASSWORD => Command::SetPassword { public: r.array()?, sealed: r.array()? },
                op::GET_ACCESS => Command::GetAccess,
                _ => Command::SetAccess(r.allow_list()?),
            };
            Request::Command { mac, auth, command }
        }
        _ => return None,
    };
    r.end()?;
    Some((id, request))
}
