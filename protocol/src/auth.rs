//! Authentication without a password on the wire (docs/security.md): a SCRAM-style
//! challenge-response over SHA-256 (RFC 5802 / RFC 7677's key schedule), shared by the
//! discovery protocol's configuration commands and the firmware update session.
//!
//! - The PC derives `SaltedPassword = PBKDF2-HMAC-SHA-256(password, salt, iterations)`,
//!   `ClientKey = HMAC(SaltedPassword, "Client Key")`, `StoredKey = SHA-256(ClientKey)` and
//!   `ServerKey = HMAC(SaltedPassword, "Server Key")` ([`derive`], with the `client` feature).
//!   The module stores only the salt, the iteration count, StoredKey and ServerKey
//!   ([`Credential`]): no slow hash ever runs on the module.
//! - A request carries `ClientProof = ClientKey XOR HMAC(StoredKey, AuthMessage)`, where the
//!   AuthMessage is every byte of the request but the proof (opcode, request id, target MAC,
//!   both nonces, every field). The module checks `SHA-256(ClientKey') == StoredKey`
//!   ([`verify_proof`]).
//! - The module answers with `ServerSignature = HMAC(ServerKey, AuthMessage || reply)`
//!   ([`server_signature`]), so the PC knows the module, not a forger, answered.
//! - A new password travels as a new [`Credential`] sealed with a key agreed by X25519 between
//!   an ephemeral key of the PC and one of the module ([`x25519`], [`seal`]): a sniffer sees
//!   neither the password nor the new keys.

use hmac::{Hmac, Mac};
use sha2::{Digest, Sha256};

/// Bytes of a nonce (the PC's and the module's).
pub const NONCE_LEN: usize = 16;
/// Bytes of a key, a proof or a signature.
pub const KEY_LEN: usize = 32;
/// Bytes of a salt.
pub const SALT_LEN: usize = 16;
/// Bytes of an encoded [`Credential`].
pub const CREDENTIAL_LEN: usize = SALT_LEN + 4 + 2 * KEY_LEN;
/// The fewest PBKDF2 iterations a module accepts in a new credential.
pub const MIN_ITERATIONS: u32 = 4096;
/// The most PBKDF2 iterations a module accepts (a PC must be able to log in in seconds).
pub const MAX_ITERATIONS: u32 = 10_000_000;
/// The shortest password our clients set (the module never sees the password: it cannot check).
pub const MIN_PASSWORD_LEN: usize = 8;
/// Factory default configuration password: it allows the manuals' first-contact commands
/// (SET_NETWORK, RESTART), not updates or allow-list changes (docs/security.md).
pub const FACTORY_PASSWORD: &str = "remodaq";

/// What the module stores of its configuration password.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Credential {
    /// PBKDF2 salt.
    pub salt: [u8; SALT_LEN],
    /// PBKDF2 iterations.
    pub iterations: u32,
    /// SHA-256(ClientKey).
    pub stored_key: [u8; KEY_LEN],
    /// HMAC(SaltedPassword, "Server Key").
    pub server_key: [u8; KEY_LEN],
}

impl Credential {
    /// The factory credential: [`FACTORY_PASSWORD`] with the salt `remodaq-factory!` and 4096
    /// iterations (public knowledge, as the factory password is).
    pub const FACTORY: Credential = Credential {
        salt: *b"remodaq-factory!",
        iterations: 4096,
        stored_key: [
            0x96, 0x5a, 0x67, 0x18, 0x64, 0x75, 0xce, 0x4c, 0x00, 0xf4, 0x02, 0x7f, 0xe5, 0x7a, 0xa3, 0x5e, 0x9f, 0xa0,
            0x9c, 0x41, 0xc7, 0x9e, 0x34, 0x32, 0xab, 0xb4, 0x92, 0x49, 0xf0, 0x1a, 0x0d, 0x67,
        ],
        server_key: [
            0x69, 0xc4, 0xb4, 0x1e, 0xd3, 0xc3, 0x9c, 0xa0, 0x3d, 0x57, 0x4c, 0x2a, 0xb7, 0x3d, 0x14, 0x52, 0x0f, 0xce,
            0x5f, 0xb6, 0xbf, 0x4c, 0xdd, 0xed, 0xbd, 0x47, 0x3c, 0x9b, 0xa1, 0x34, 0xc0, 0x6d,
        ],
    };

    /// Whether this is the factory password's credential (any salt or iteration count).
    pub fn is_factory(&self) -> bool {
        self.stored_key == Self::FACTORY.stored_key
    }

    /// Whether a module may take this credential: iterations in range, keys not all zero.
    pub fn is_acceptable(&self) -> bool {
        (MIN_ITERATIONS..=MAX_ITERATIONS).contains(&self.iterations)
            && self.stored_key != [0; KEY_LEN]
            && self.server_key != [0; KEY_LEN]
    }

    /// The encoded credential: salt, iterations (big-endian), StoredKey, ServerKey.
    pub fn encode(&self) -> [u8; CREDENTIAL_LEN] {
        let mut out = [0u8; CREDENTIAL_LEN];
        out[..16].copy_from_slice(&self.salt);
        out[16..20].copy_from_slice(&self.iterations.to_be_bytes());
        out[20..52].copy_from_slice(&self.stored_key);
        out[52..].copy_from_slice(&self.server_key);
        out
    }

    /// Decodes [`Self::encode`]'s bytes.
    pub fn decode(b: &[u8; CREDENTIAL_LEN]) -> Self {
        let mut c = Credential { salt: [0; 16], iterations: 0, stored_key: [0; 32], server_key: [0; 32] };
        c.salt.copy_from_slice(&b[..16]);
        c.iterations = u32::from_be_bytes([b[16], b[17], b[18], b[19]]);
        c.stored_key.copy_from_slice(&b[20..52]);
        c.server_key.copy_from_slice(&b[52..]);
        c
    }
}

/// A domain tag (security review of 4cfaadc, "label prefixes"): a label's length in one byte,
/// then the label, as a `&'static [u8]` made at compile time. Every proof, signature, sealing
/// key and keystream block of the protocols starts its HMAC message with one, so that two
/// messages of different labels never coincide, whatever the labels: two tags are equal only
/// when their labels are, and no tag is a prefix of another (a label that was a prefix of
/// another, `"RDAQ update v2"` of `"RDAQ update v2 answer"`, no longer is one once tagged).
/// One label serves two messages only where their keys differ (a web login's proof, under the
/// StoredKey, and the module's signature of it, under the ServerKey). The page's JavaScript (`tag` in services/web/web/auth.js) and the Python tools make
/// the same bytes.
#[macro_export]
macro_rules! domain_tag {
    ($label:literal) => {{
        const LABEL: &[u8] = $label;
        const TAG: [u8; LABEL.len() + 1] = $crate::auth::tag_of(LABEL);
        &TAG
    }};
}

/// The bytes of [`domain_tag!`]: `label.len()` (below 256), then `label`; `N` must be one more
/// than the label's length (a build error otherwise).
pub const fn tag_of<const N: usize>(label: &[u8]) -> [u8; N] {
    assert!(label.len() + 1 == N && label.len() < 256, "a domain tag's label is 0-255 bytes");
    let mut out = [0u8; N];
    out[0] = label.len() as u8;
    let mut i = 0;
    while i < label.len() {
        out[i + 1] = label[i];
        i += 1;
    }
    out
}

/// HMAC-SHA-256 of the concatenation of `parts`.
pub fn hmac(key: &[u8], parts: &[&[u8]]) -> [u8; KEY_LEN] {
    // HMAC takes keys of any length: `new_from_slice` cannot fail for it.
    let mut mac = match <Hmac<Sha256> as Mac>::new_from_slice(key) {
        Ok(mac) => mac,
        Err(_) => return [0; KEY_LEN],
    };
    for part in parts {
        mac.update(part);
    }
    mac.finalize().into_bytes().into()
}

fn xor(a: &[u8; KEY_LEN], b: &[u8; KEY_LEN]) -> [u8; KEY_LEN] {
    let mut out = [0u8; KEY_LEN];
    for (o, (x, y)) in out.iter_mut().zip(a.iter().zip(b)) {
        *o = x ^ y;
    }
    out
}

/// Equality in constant time.
pub fn same(a: &[u8; KEY_LEN], b: &[u8; KEY_LEN]) -> bool {
    a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// The PC's proof over the AuthMessage `message` (given in parts).
pub fn client_proof(client_key: &[u8; KEY_LEN], message: &[&[u8]]) -> [u8; KEY_LEN] {
    let stored: [u8; KEY_LEN] = Sha256::digest(client_key).into();
    xor(client_key, &hmac(&stored, message))
}

/// The module's check of a proof: the ClientKey it recovers (the key of the session's sealed
/// fields, [`seal`]) if the proof is right, `None` otherwise.
pub fn verify_proof(stored_key: &[u8; KEY_LEN], message: &[&[u8]], proof: &[u8; KEY_LEN]) -> Option<[u8; KEY_LEN]> {
    let client_key = xor(proof, &hmac(stored_key, message));
    let stored: [u8; KEY_LEN] = Sha256::digest(client_key).into();
    same(&stored, stored_key).then_some(client_key)
}

/// The module's signature over the AuthMessage and its reply (given in parts).
pub fn server_signature(server_key: &[u8; KEY_LEN], message: &[&[u8]]) -> [u8; KEY_LEN] {
    hmac(server_key, message)
}

/// X25519 (RFC 7748): `scalar` times the point `u` (the base point is [`BASE_POINT`]).
pub fn x25519(scalar: &[u8; KEY_LEN], u: &[u8; KEY_LEN]) -> [u8; KEY_LEN] {
    salty::agreement::x25519(*scalar, *u)
}

/// The X25519 base point (u = 9).
pub const BASE_POINT: [u8; KEY_LEN] = {
    let mut b = [0u8; KEY_LEN];
    b[0] = 9;
    b
};

/// Encrypts or decrypts `data` in place (XOR with an HMAC-SHA-256 keystream under a key derived
/// from the X25519 `shared` secret and `context`). Integrity comes from the proof that covers
/// the sealed bytes.
pub fn seal(shared: &[u8; KEY_LEN], context: &[&[u8]], data: &mut [u8]) {
    let key = hmac(shared, context);
    for (block, chunk) in data.chunks_mut(KEY_LEN).enumerate() {
        let stream = hmac(&key, &[SEAL_STREAM_LABEL, &[block as u8]]);
        for (d, s) in chunk.iter_mut().zip(stream.iter()) {
            *d ^= s;
        }
    }
}

/// Domain tag of a seal's keystream blocks.
const SEAL_STREAM_LABEL: &[u8] = crate::domain_tag!(b"RDAQ seal");

/// Bytes of a sealed credential's key confirmation.
pub const SEAL_TAG_LEN: usize = 16;
/// Bytes of a sealed credential: the credential XORed with the keystream, then its tag.
pub const SEALED_LEN: usize = CREDENTIAL_LEN + SEAL_TAG_LEN;
/// Label of the key confirmation of a sealed credential.
const SEAL_TAG_LABEL: &[u8] = crate::domain_tag!(b"RDAQ seal confirm");

fn seal_tag(shared: &[u8; KEY_LEN], context: &[&[u8]], ciphertext: &[u8]) -> [u8; SEAL_TAG_LEN] {
    let key = hmac(shared, context);
    let mac = hmac(&key, &[SEAL_TAG_LABEL, ciphertext]);
    let mut tag = [0u8; SEAL_TAG_LEN];
    tag.copy_from_slice(&mac[..SEAL_TAG_LEN]);
    tag
}

/// Seals `credential` for the key agreed (`shared`, `context`): [`seal`]ed, then a key
/// confirmation over the sealed bytes (encrypt, then MAC). A seal made for any other key does
/// not open (security review finding 8: without it, such a seal opened to random bytes that
/// passed as a credential about once in 430 tries, locking the module).
pub fn seal_credential(shared: &[u8; KEY_LEN], context: &[&[u8]], credential: &Credential) -> [u8; SEALED_LEN] {
    let mut out = [0u8; SEALED_LEN];
    let (body, tag) = out.split_at_mut(CREDENTIAL_LEN);
    body.copy_from_slice(&credential.encode());
    seal(shared, context, body);
    tag.copy_from_slice(&seal_tag(shared, context, body));
    out
}

/// Opens a [`seal_credential`]: the credential, or `None` when the tag shows that it was
/// sealed for another key (or changed on the way); nothing is decrypted then.
pub fn open_credential(shared: &[u8; KEY_LEN], context: &[&[u8]], sealed: &[u8; SEALED_LEN]) -> Option<Credential> {
    let (body, tag) = sealed.split_at(CREDENTIAL_LEN);
    let expected = seal_tag(shared, context, body);
    if expected.iter().zip(tag).fold(0u8, |acc, (x, y)| acc | (x ^ y)) != 0 {
        return None;
    }
    let mut bytes = [0u8; CREDENTIAL_LEN];
    bytes.copy_from_slice(body);
    seal(shared, context, &mut bytes);
    Some(Credential::decode(&bytes))
}

/// The PC side: ClientKey and the credential of `password` with `salt` and `iterations`.
#[cfg(any(feature = "client", test))]
pub fn derive(password: &[u8], salt: &[u8; SALT_LEN], iterations: u32) -> ([u8; KEY_LEN], Credential) {
    let mut salted = [0u8; KEY_LEN];
    pbkdf2::pbkdf2_hmac::<Sha256>(password, salt, iterations, &mut salted);
    let client_key = hmac(&salted, &[b"Client Key"]);
    let credential = Credential {
        salt: *salt,
        iterations,
        stored_key: Sha256::digest(client_key).into(),
        server_key: hmac(&salted, &[b"Server Key"]),
    };
    (client_key, credential)
}

/// The SHA-256 fingerprint of a public key, as INFO and the diagnostics registers show it:
/// its first 8 bytes.
pub fn fingerprint(public_key: &[u8; KEY_LEN]) -> [u8; 8] {
    let d: [u8; 32] = Sha256::digest(public_key).into();
    let mut out = [0u8; 8];
    out.copy_from_slice(&d[..8]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every label of the protocols as a domain tag: its length in a byte, then its text; no tag
    /// is a prefix of another (the review's "label prefixes": the update labels were).
    #[test]
    fn domain_tags_are_length_prefixed_and_none_is_a_prefix_of_another() {
        assert_eq!(crate::domain_tag!(b"RDAQ seal"), b"\x09RDAQ seal");
        assert_eq!(crate::update::UPDATE_LABEL, b"\x0eRDAQ update v2");
        let tags: [&[u8]; 14] = [
            crate::update::UPDATE_LABEL,
            crate::update::ANSWER_LABEL,
            crate::discovery::CLIENT_LABEL,
            crate::discovery::SERVER_LABEL,
            crate::discovery::SEAL_LABEL,
            crate::web::PASSWORD_SEAL_LABEL,
            crate::web::MQTT_CREDENTIALS_LABEL,
            crate::web::MQTT_BINDING_LABEL,
            crate::web::AGREEMENT_LABEL,
            crate::web::LOGIN_LABEL,
            crate::web::SESSION_LABEL,
            crate::web::REQUEST_LABEL,
            SEAL_STREAM_LABEL,
            SEAL_TAG_LABEL,
        ];
        for (i, a) in tags.iter().enumerate() {
            assert_eq!(a[0] as usize, a.len() - 1, "{a:?}");
            for (j, b) in tags.iter().enumerate() {
                assert!(i == j || !b.starts_with(a), "{a:?} is a prefix of {b:?}");
            }
        }
    }

    fn unhex<const N: usize>(s: &str) -> [u8; N] {
        let mut out = [0u8; N];
        for (i, o) in out.iter_mut().enumerate() {
            *o = u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap();
        }
        out
    }

    /// RFC 7677 §3's SCRAM-SHA-256 example: user "user", password "pencil".
    #[cfg(any(feature = "client", test))]
    #[test]
    fn rfc7677_example() {
        // salt W22ZaJ0SNY7soEsUEjb6gQ==, proof dHzbZapWIk4jUhN+Ute9ytag9zjfMHgsqmmiz7AndVQ=,
        // server signature 6rriTRBi23WpRR/wtup+mMhUZUn/dB5nLTJRsjl95G4= (base64, in hex below).
        let salt: [u8; 16] = unhex("5b6d99689d12358eeca04b141236fa81");
        let proof: [u8; 32] = unhex("747cdb65aa56224e2352137e52d7bdcad6a0f738df30782caa69a2cfb0277554");
        let signature: [u8; 32] = unhex("eabae24d1062db75a9451ff0b6ea7e98c8546549ff741e672d3251b2397de46e");
        let auth_message = "n=user,r=rOprNGfwEbeRWgbNEkqO,\
            r=rOprNGfwEbeRWgbNEkqO%hvYDpWUa2RaTCAfuxFIlj)hNlF$k0,s=W22ZaJ0SNY7soEsUEjb6gQ==,i=4096,\
            c=biws,r=rOprNGfwEbeRWgbNEkqO%hvYDpWUa2RaTCAfuxFIlj)hNlF$k0";
        let (client_key, credential) = derive(b"pencil", &salt, 4096);
        let message: &[&[u8]] = &[auth_message.as_bytes()];
        assert_eq!(client_proof(&client_key, message), proof);
        assert_eq!(server_signature(&credential.server_key, message), signature);
        assert_eq!(verify_proof(&credential.stored_key, message, &proof), Some(client_key));
        let mut bad = proof;
        bad[0] ^= 1;
        assert_eq!(verify_proof(&credential.stored_key, message, &bad), None);
        assert_eq!(verify_proof(&credential.stored_key, &[b"other"], &proof), None);
    }

    /// The factory constants are what PBKDF2 gives for "remodaq" (computed independently with
    /// Python's hashlib: the literals above).
    #[cfg(any(feature = "client", test))]
    #[test]
    fn factory_credential() {
        let (_, c) = derive(FACTORY_PASSWORD.as_bytes(), &Credential::FACTORY.salt, 4096);
        assert_eq!(c, Credential::FACTORY);
        assert!(c.is_factory() && c.is_acceptable());
        assert_eq!(Credential::decode(&c.encode()), c);
    }

    /// RFC 7748 §5.2's first X25519 test vector, and §6.1's key agreement.
    #[test]
    fn x25519_rfc7748() {
        let scalar = unhex("a546e36bf0527c9d3b16154b82465edd62144c0ac1fc5a18506a2244ba449ac4");
        let u = unhex("e6db6867583030db3594c1a424b15f7c726624ec26b3353b10a903a6d0ab1c4c");
        let out: [u8; 32] = unhex("c3da55379de9c6908e94ea4df28d084f32eccf03491c71f754b4075577a28552");
        assert_eq!(x25519(&scalar, &u), out);
        let alice = unhex("77076d0a7318a57d3c16c17251b26645df4c2f87ebc0992ab177fba51db92c2a");
        let bob = unhex("5dab087e624a8a4b79e17f8b83800ee66f3bb1292618b6fd1c2f8b27ff88e0eb");
        let shared: [u8; 32] = unhex("4a5d9d5ba4ce2de1728e3bf480350f25e07e21c947d19e3376f09b3c1e161742");
        let (a_pub, b_pub) = (x25519(&alice, &BASE_POINT), x25519(&bob, &BASE_POINT));
        assert_eq!(a_pub, unhex::<32>("8520f0098930a754748b7ddcb43ef75a0dbf3a0d26381af4eba4a98eaa9b4e6a"));
        assert_eq!(x25519(&alice, &b_pub), shared);
        assert_eq!(x25519(&bob, &a_pub), shared);
    }

    #[test]
    fn seal_round_trip() {
        let data = *b"a credential of some eighty-four bytes, sealed in three blocks of the keystream..";
        let mut sealed = data;
        seal(&[7; 32], &[b"ctx"], &mut sealed);
        assert_ne!(sealed, data);
        let mut other = sealed;
        seal(&[7; 32], &[b"ctx2"], &mut other);
        assert_ne!(other, data, "another context, another key");
        seal(&[7; 32], &[b"ctx"], &mut sealed);
        assert_eq!(sealed, data);
    }
}
