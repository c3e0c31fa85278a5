//! Firmware update (TCP, port [`PORT`]): the signed image file and the session's wire format.
//! See `docs/update.md`.
//!
//! An image file is a [`Header`] then the firmware bytes. The signature is ed25519 over the
//! SHA-512 digest of the firmware bytes (what `embassy-boot` verifies before it marks the
//! update). A session authenticates as the discovery protocol's commands do (`crate::auth`,
//! docs/security.md), with no password on the wire:
//! 1. the PC sends its nonce ([`NONCE_LEN`] bytes);
//! 2. the module answers a [`Greeting`]: its MAC, the salt and iterations of its password, its
//!    nonce (new for this session) and its flags;
//! 3. the PC sends its proof over [`auth_message`] (which covers the header), then the header;
//! 4. the module answers a [`Status`] byte (go on, or why not), signed when given after a right
//!    proof ([`answer_message`]);
//! 5. the PC sends the firmware bytes; the module answers a last signed status (verified and
//!    marked, or why not), then restarts into the new image when it is [`Status::Ok`].
//!
//! The handshake (1-3) must be done within [`HANDSHAKE_S`] seconds, and a session whose peer
//! sends nothing for [`HANDSHAKE_S`] seconds ends.

use crate::auth::{KEY_LEN, NONCE_LEN, SALT_LEN};

/// Seconds the handshake may take, and the longest silence of a peer in a session.
pub const HANDSHAKE_S: u64 = 10;
/// Label of the AuthMessage of an update session.
pub const UPDATE_LABEL: &[u8] = b"RDAQ update v2";
/// Label of the module's signatures in an update session.
pub const ANSWER_LABEL: &[u8] = b"RDAQ update v2 answer";
/// Bytes of an encoded [`Greeting`].
pub const GREETING_LEN: usize = 6 + SALT_LEN + 4 + NONCE_LEN + 1;

/// The module's first answer in a session.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Greeting {
    /// The module's MAC address.
    pub mac: [u8; 6],
    /// The salt of its password.
    pub salt: [u8; SALT_LEN],
    /// Its PBKDF2 iterations.
    pub iterations: u32,
    /// The module's nonce for this session.
    pub snonce: [u8; NONCE_LEN],
    /// `crate::discovery::info_flags`.
    pub flags: u8,
}

impl Greeting {
    /// The encoded greeting.
    pub fn encode(&self) -> [u8; GREETING_LEN] {
        let mut out = [0u8; GREETING_LEN];
        out[..6].copy_from_slice(&self.mac);
        out[6..22].copy_from_slice(&self.salt);
        out[22..26].copy_from_slice(&self.iterations.to_be_bytes());
        out[26..42].copy_from_slice(&self.snonce);
        out[42] = self.flags;
        out
    }
    /// Decodes [`Self::encode`]'s bytes.
    pub fn decode(b: &[u8; GREETING_LEN]) -> Self {
        let mut g = Greeting { mac: [0; 6], salt: [0; SALT_LEN], iterations: 0, snonce: [0; NONCE_LEN], flags: b[42] };
        g.mac.copy_from_slice(&b[..6]);
        g.salt.copy_from_slice(&b[6..22]);
        g.iterations = u32::from_be_bytes([b[22], b[23], b[24], b[25]]);
        g.snonce.copy_from_slice(&b[26..42]);
        g
    }
}

/// The AuthMessage of a session: what the PC's proof covers.
pub fn auth_message<'a>(
    mac: &'a [u8; 6],
    cnonce: &'a [u8; NONCE_LEN],
    snonce: &'a [u8; NONCE_LEN],
    header: &'a [u8; HEADER_LEN],
) -> [&'a [u8]; 5] {
    [UPDATE_LABEL, mac, cnonce, snonce, header]
}

/// What the module signs for an answer `status` at `step` (0 after the header, 1 after the
/// firmware) of a session with AuthMessage `message`.
pub fn answer_message<'a>(message: &[&'a [u8]; 5], step: &'a [u8; 1], status: &'a [u8; 1]) -> [&'a [u8]; 7] {
    [ANSWER_LABEL, message[1], message[2], message[3], message[4], step, status]
}

/// Bytes of a signed answer: the status, then the signature.
pub const SIGNED_ANSWER_LEN: usize = 1 + KEY_LEN;

/// The TCP port of the update service.
pub const PORT: u16 = 8301;
/// First bytes of an image file.
pub const MAGIC: [u8; 4] = *b"RDQU";
/// Image file format version.
pub const FORMAT: u8 = 1;
/// Bytes of an encoded [`Header`].
pub const HEADER_LEN: usize = 4 + 1 + 1 + 2 + 2 + 4 + 64;

/// The header of an image file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Module name register value the image is for (8318h, 8350h).
    pub model: u16,
    /// Firmware version of the image (register 40213).
    pub version: u16,
    /// Length of the firmware bytes that follow.
    pub length: u32,
    /// ed25519 signature of the SHA-512 digest of the firmware bytes.
    pub signature: [u8; 64],
}

impl Header {
    /// The encoded header.
    pub fn encode(&self) -> [u8; HEADER_LEN] {
        let mut out = [0u8; HEADER_LEN];
        out[..4].copy_from_slice(&MAGIC);
        out[4] = FORMAT;
        out[6..8].copy_from_slice(&self.model.to_be_bytes());
        out[8..10].copy_from_slice(&self.version.to_be_bytes());
        out[10..14].copy_from_slice(&self.length.to_be_bytes());
        out[14..].copy_from_slice(&self.signature);
        out
    }

    /// Decodes a header; `None` for another magic, format or a reserved byte not 0.
    pub fn decode(bytes: &[u8; HEADER_LEN]) -> Option<Self> {
        if bytes[..4] != MAGIC || bytes[4] != FORMAT || bytes[5] != 0 {
            return None;
        }
        let mut signature = [0u8; 64];
        signature.copy_from_slice(&bytes[14..]);
        Some(Self {
            model: u16::from_be_bytes([bytes[6], bytes[7]]),
            version: u16::from_be_bytes([bytes[8], bytes[9]]),
            length: u32::from_be_bytes([bytes[10], bytes[11], bytes[12], bytes[13]]),
            signature,
        })
    }
}

/// The module's answers in a session: the status codes of the discovery protocol's commands
/// (0 ok, 1 wrong password, 2 rate limited, 3 not an image for this module, 4 the update
/// partition could not be written), and 5 for a signature that does not match.
pub use crate::discovery::Status;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trip() {
        let h = Header { model: 0x8350, version: 0xA101, length: 123_456, signature: [7; 64] };
        let bytes = h.encode();
        assert_eq!(&bytes[..14], b"RDQU\x01\x00\x83\x50\xA1\x01\x00\x01\xE2\x40");
        assert_eq!(Header::decode(&bytes), Some(h));
        let mut bad = bytes;
        bad[4] = 2;
        assert_eq!(Header::decode(&bad), None);
        assert_eq!(Status::from_code(5), Some(Status::BadSignature));
    }
}
