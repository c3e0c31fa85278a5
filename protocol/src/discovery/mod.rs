//! The network discovery and configuration protocol (UDP, port [`PORT`]), the codec only; see
//! `docs/discovery.md` for the wire format and `docs/security.md` for its authentication.
//! [`decode_request`] is pure and total (fuzzed); the module side's service is in
//! `remodaq-shared`, the PC side in the `remodaq` utility ([`client`], with the `client`
//! feature).
//!
//! Commands that change or reveal settings are authenticated ([`Auth`], `crate::auth`): no
//! password crosses the wire, each proof is bound to a single-use nonce of the module and to
//! every byte of its request, and the module signs its answer.

mod reply;
mod request;
mod wire;

pub use crate::status::Status;
pub use reply::{
    decode_challenge, decode_info, decode_reply, encode_challenge, info_flags, Challenge, Info, Reply, NONCE_LIFETIME_S,
};
pub use request::{auth_message, decode_request, encode_request, Auth, Command, Request};
pub use wire::{
    op, Writer, CLIENT_LABEL, HEADER_LEN, MAGIC, MAX_DATAGRAM, PORT, PROOF_AT, SEAL_LABEL, SERVER_LABEL, VERSION,
};

/// The PC side of authentication: proofs and the check of the module's signature.
#[cfg(any(feature = "client", test))]
pub mod client {
    use super::*;
    use crate::access::AllowList;
    use crate::auth::{self, KEY_LEN, NONCE_LEN, SALT_LEN};
    use crate::net::NetConfig;

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
        let sealed = auth::seal_credential(&shared, &[SEAL_LABEL, cnonce, &challenge.snonce], new);
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
