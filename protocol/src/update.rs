//! Firmware update (TCP, port [`PORT`]): the signed image file and the session's wire format.
//! See `docs/update.md`.
//!
//! An image file is a [`Header`] then the firmware bytes. The header names the model, the
//! version, a security counter, the length and the SHA-512 digest of the firmware bytes; its
//! ed25519 signature covers all of that (the first [`SIGNED_LEN`] bytes), so neither the model
//! nor the version nor the counter can be changed without the signing key. The module checks
//! the model and the counter before it takes the firmware, the digest and the signature after;
//! the bootloaders check digest and signature again before a swap, and the model and counter
//! against the [`Identity`] compiled into the running image ([`check_before_swap`]). A session authenticates as the discovery protocol's commands do (`crate::auth`,
//! docs/security.md), with no password on the wire:
//! 1. the PC sends the session's [`OPENING`] (magic and version), then its nonce
//!    ([`NONCE_LEN`] bytes); a stream that opens otherwise is closed at once, before anything
//!    is read as a proof;
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

/// The first bytes of every session, from the PC: a magic and the session format's version.
/// The NUL bytes keep it out of reach of a browser page (security review finding 7): an HTTP
/// request opens with its method and a space, never a NUL, so the module closes a browser's
/// connection after its first 8 bytes, without reading a proof or spending the guessing budget.
/// Version 4: the proofs' messages start with domain tags (a PC tool of version 3 is closed at
/// once, rather than answered "wrong password").
pub const OPENING: [u8; 8] = *b"RDAQ\x00UP\x04";

/// Seconds the handshake may take, and the longest silence of a peer in a session.
pub const HANDSHAKE_S: u64 = 10;
/// Domain tag of the AuthMessage of an update session (`crate::domain_tag!`).
pub const UPDATE_LABEL: &[u8] = crate::domain_tag!(b"RDAQ update v2");
/// Domain tag of the module's signatures in an update session.
pub const ANSWER_LABEL: &[u8] = crate::domain_tag!(b"RDAQ update v2 answer");
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
/// Image file format version (2: the signature covers the header).
pub const FORMAT: u8 = 2;
/// Bytes of a [`Header`] the signature covers.
pub const SIGNED_LEN: usize = 4 + 1 + 1 + 2 + 2 + 4 + 4 + 64;
/// Bytes of an encoded [`Header`].
pub const HEADER_LEN: usize = SIGNED_LEN + 64;

/// The header of an image file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Module name register value the image is for (8318h, 8350h).
    pub model: u16,
    /// Firmware version of the image (register 40213).
    pub version: u16,
    /// Security counter: a module refuses an image whose counter is below the highest it has
    /// confirmed (anti-rollback, docs/update.md).
    pub counter: u32,
    /// Length of the firmware bytes that follow.
    pub length: u32,
    /// SHA-512 of the firmware bytes.
    pub digest: [u8; 64],
    /// ed25519 signature of the first [`SIGNED_LEN`] bytes of the encoded header.
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
        out[10..14].copy_from_slice(&self.counter.to_be_bytes());
        out[14..18].copy_from_slice(&self.length.to_be_bytes());
        out[18..82].copy_from_slice(&self.digest);
        out[82..].copy_from_slice(&self.signature);
        out
    }

    /// Decodes a header; `None` for another magic, format or a reserved byte not 0.
    pub fn decode(bytes: &[u8; HEADER_LEN]) -> Option<Self> {
        if bytes[..4] != MAGIC || bytes[4] != FORMAT || bytes[5] != 0 {
            return None;
        }
        let mut digest = [0u8; 64];
        digest.copy_from_slice(&bytes[18..82]);
        let mut signature = [0u8; 64];
        signature.copy_from_slice(&bytes[82..]);
        Some(Self {
            model: u16::from_be_bytes([bytes[6], bytes[7]]),
            version: u16::from_be_bytes([bytes[8], bytes[9]]),
            counter: u32::from_be_bytes([bytes[10], bytes[11], bytes[12], bytes[13]]),
            length: u32::from_be_bytes([bytes[14], bytes[15], bytes[16], bytes[17]]),
            digest,
            signature,
        })
    }

    /// Whether the signature is `key`'s over this header, and `digest` (of the firmware bytes
    /// as received or as in flash) is the one it names.
    pub fn verify(&self, digest: &[u8; 64], key: &[u8; 32]) -> bool {
        let encoded = self.encode();
        let Ok(public) = salty::PublicKey::try_from(key) else { return false };
        self.digest == *digest
            && public.verify(&encoded[..SIGNED_LEN], &salty::Signature::from(&self.signature)).is_ok()
    }
}

/// Where every firmware image carries its [`Identity`]: this many bytes from its start, after
/// the vector table (both boards' memory.x place the section `.remodaq_identity` there and
/// start `.text` after it).
pub const IDENTITY_AT: u32 = 0x400;
/// Bytes of an encoded [`Identity`].
pub const IDENTITY_LEN: usize = 16;
/// The first bytes of an encoded [`Identity`].
pub const IDENTITY_MAGIC: [u8; 8] = *b"RDQ\x00ID\x00\x01";

/// What an image is, compiled into it at [`IDENTITY_AT`] (security review finding 11c): the
/// model it runs on and its security counter. `remodaq sign` signs an image only with the
/// model and counter its identity names, so the signed header and the bytes agree; the
/// bootloaders compare a marked update's with the running image's before a swap, without the
/// application's settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Identity {
    /// Module name register value (8318h, 8350h).
    pub model: u16,
    /// The security counter (anti-rollback) the image was built with.
    pub counter: u32,
}

impl Identity {
    /// The encoded identity: magic, model, two zero bytes, counter (big-endian).
    pub const fn encode(&self) -> [u8; IDENTITY_LEN] {
        let mut out = [0u8; IDENTITY_LEN];
        let mut i = 0;
        while i < IDENTITY_MAGIC.len() {
            out[i] = IDENTITY_MAGIC[i];
            i += 1;
        }
        let model = self.model.to_be_bytes();
        let counter = self.counter.to_be_bytes();
        out[8] = model[0];
        out[9] = model[1];
        out[12] = counter[0];
        out[13] = counter[1];
        out[14] = counter[2];
        out[15] = counter[3];
        out
    }

    /// Decodes an identity; `None` for another magic or a reserved byte not 0.
    pub fn decode(bytes: &[u8; IDENTITY_LEN]) -> Option<Self> {
        if bytes[..8] != IDENTITY_MAGIC || bytes[10..12] != [0, 0] {
            return None;
        }
        Some(Self {
            model: u16::from_be_bytes([bytes[8], bytes[9]]),
            counter: u32::from_be_bytes([bytes[12], bytes[13], bytes[14], bytes[15]]),
        })
    }

    /// The identity in a firmware binary (as `llvm-objcopy -O binary` writes it); `None` when
    /// it has none.
    pub fn of_firmware(firmware: &[u8]) -> Option<Self> {
        let at = IDENTITY_AT as usize;
        let bytes: &[u8; IDENTITY_LEN] = firmware.get(at..at + IDENTITY_LEN)?.try_into().ok()?;
        Self::decode(bytes)
    }
}

/// The SHA-512 of `length` bytes read through `read` (offset, buffer; false: a read error) in
/// chunks of `chunk.len()`; `None` on a read error.
pub fn digest_of(length: u32, chunk: &mut [u8], mut read: impl FnMut(u32, &mut [u8]) -> bool) -> Option<[u8; 64]> {
    // salty's SHA-512 (what its ed25519 uses anyway): about 1 KiB of code, where the sha2
    // crate's unrolled one is 28 KiB, too much for the 32 KiB bootloaders.
    let mut hash = salty::Sha512::new();
    let mut offset = 0u32;
    while offset < length {
        let n = ((length - offset) as usize).min(chunk.len());
        if !read(offset, &mut chunk[..n]) {
            return None;
        }
        hash.update(&chunk[..n]);
        offset += n as u32;
    }
    Some(hash.finalize())
}

/// What a bootloader does with the update partition before it lets embassy-boot run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BeforeSwap {
    /// No swap is about to start (none requested, one under way, or a revert): go on.
    Nothing,
    /// A swap is requested and its image checks out: go on.
    Verified,
    /// A swap is requested, but the update partition holds no image signed with the key (its
    /// manifest missing or changed, its firmware changed): cancel the swap (mark booted). A
    /// cancel that fails must not lead to the swap either: the bootloader restarts and checks
    /// again.
    Refuse,
    /// The state partition cannot be read, so nobody knows whether a swap is asked for: neither
    /// swap nor start anything; the bootloader restarts and reads again (fail closed).
    Unreadable,
}

/// The bootloaders' check before a swap: if the state partition asks for one that has not
/// started (embassy-boot's layout: the swap magic in the first word, its progress words still
/// erased), the manifest the application wrote at the start of the update partition's last
/// page (`manifest_at`, the swap's scratch page, which the swap's first step overwrites) must
/// be a header signed with `key` whose digest is that of the firmware in the partition, and
/// whose model and security counter are the [`Identity`] of that firmware, the running image's
/// model (in `active`), and a counter not below the running image's (security review finding
/// 11c: the application checks both before it marks an update; this check does not rely on it).
/// A running image without an identity takes no update (fail closed).
#[cfg(feature = "bootloader")]
pub fn check_before_swap<A, D, S>(
    active: &mut A,
    dfu: &mut D,
    state: &mut S,
    manifest_at: u32,
    key: &[u8; 32],
) -> BeforeSwap
where
    A: embedded_storage::nor_flash::ReadNorFlash,
    D: embedded_storage::nor_flash::ReadNorFlash,
    S: embedded_storage::nor_flash::NorFlash,
{
    /// embassy-boot 0.7's swap magic and erased state value (`lib.rs`).
    const SWAP_MAGIC: u8 = 0xF0;
    const ERASED: u8 = 0xFF;
    let write = S::WRITE_SIZE.clamp(1, 32);
    let mut word = [0u8; 32];
    let mut read_word = |at: usize, out: &mut [u8; 32]| state.read((at * write) as u32, &mut out[..write]).is_ok();
    if !read_word(0, &mut word) {
        return BeforeSwap::Unreadable;
    }
    if word[..write].iter().any(|&b| b != SWAP_MAGIC) {
        return BeforeSwap::Nothing;
    }
    // Progress valid (word 1) and the first progress index (word 2) still erased: not started.
    for at in [1, 2] {
        if !read_word(at, &mut word) {
            return BeforeSwap::Unreadable;
        }
        if word[..write].iter().any(|&b| b != ERASED) {
            return BeforeSwap::Nothing;
        }
    }
    let mut header = [0u8; HEADER_LEN];
    if dfu.read(manifest_at, &mut header).is_err() {
        return BeforeSwap::Refuse;
    }
    let Some(header) = Header::decode(&header).filter(|h| h.length <= manifest_at) else {
        return BeforeSwap::Refuse;
    };
    let running = identity_in(active);
    let marked = identity_in(dfu);
    let named = Identity { model: header.model, counter: header.counter };
    match (running, marked) {
        (Some(running), Some(marked))
            if marked == named
                && header.length >= IDENTITY_AT + IDENTITY_LEN as u32
                && named.model == running.model
                && named.counter >= running.counter => {}
        _ => return BeforeSwap::Refuse,
    }
    let mut chunk = [0u8; 256];
    match digest_of(header.length, &mut chunk, |at, buf| dfu.read(at, buf).is_ok()) {
        Some(digest) if header.verify(&digest, key) => BeforeSwap::Verified,
        _ => BeforeSwap::Refuse,
    }
}

/// The [`Identity`] of the image in `flash`; `None` when it cannot be read or is none.
#[cfg(feature = "bootloader")]
fn identity_in<F: embedded_storage::nor_flash::ReadNorFlash>(flash: &mut F) -> Option<Identity> {
    let mut bytes = [0u8; IDENTITY_LEN];
    flash.read(IDENTITY_AT, &mut bytes).ok()?;
    Identity::decode(&bytes)
}

/// The module's answers in a session: the status codes of the discovery protocol's commands
/// (0 ok, 1 wrong password, 2 rate limited, 3 not an image for this module, 4 the update
/// partition could not be written), and 5 for a signature that does not match.
pub use crate::status::Status;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_round_trip_and_place() {
        let identity = Identity { model: 0x8350, counter: 0x0102_0304 };
        let bytes = identity.encode();
        assert_eq!(&bytes[..], b"RDQ\x00ID\x00\x01\x83\x50\x00\x00\x01\x02\x03\x04");
        assert_eq!(Identity::decode(&bytes), Some(identity));
        let mut reserved = bytes;
        reserved[10] = 1;
        assert_eq!(Identity::decode(&reserved), None);
        let mut firmware = [0xA5; 0x500];
        firmware[0x400..0x410].copy_from_slice(&bytes);
        assert_eq!(Identity::of_firmware(&firmware), Some(identity));
        assert_eq!(Identity::of_firmware(&firmware[..0x40F]), None, "too short");
        assert_eq!(Identity::of_firmware(&[0xA5; 0x500]), None, "none");
    }

    #[test]
    fn header_round_trip() {
        let h =
            Header { model: 0x8350, version: 0xA101, counter: 7, length: 123_456, digest: [3; 64], signature: [7; 64] };
        let bytes = h.encode();
        assert_eq!(&bytes[..18], b"RDQU\x02\x00\x83\x50\xA1\x01\x00\x00\x00\x07\x00\x01\xE2\x40");
        assert_eq!(Header::decode(&bytes), Some(h));
        let mut bad = bytes;
        bad[4] = 1;
        assert_eq!(Header::decode(&bad), None, "format 1 (unsigned header) is not taken");
        assert_eq!(Status::from_code(5), Some(Status::BadSignature));
    }

    /// RFC 8032 §7.1 TEST 1: the empty message's signature verifies with salty (the check the
    /// module and the bootloaders run).
    #[test]
    fn ed25519_rfc8032_test_1() {
        let hex = |s: &str| -> std::vec::Vec<u8> {
            (0..s.len() / 2).map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap()).collect()
        };
        let public: [u8; 32] =
            hex("d75a980182b10ab7d54bfed3c964073a0ee172f3daa62325af021a68f707511a").try_into().unwrap();
        let signature: [u8; 64] = hex("e5564300c360ac729086e2cc806e828a84877f1eb8e5d974d873e065224901555fb8821590a33bacc61e39701cf9b46bd25bf5f0595bbe24655141438e7a100b").try_into().unwrap();
        let key = salty::PublicKey::try_from(&public).unwrap();
        assert!(key.verify(b"", &salty::Signature::from(&signature)).is_ok());
        assert!(key.verify(b"x", &salty::Signature::from(&signature)).is_err());
    }
}
