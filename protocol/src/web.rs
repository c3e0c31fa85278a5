//! The web console's authentication (issue #25, docs/web.md): the challenge-response of
//! [`crate::auth`] carried over HTTP, and a session key that signs every state-changing request.
//! No bearer secret crosses the wire: neither the password, nor a key, nor a cookie.
//!
//! 1. The page asks for a challenge: the module's salt and iteration count, and a fresh
//!    16-byte module nonce (`POST /api/v1/session/challenge`).
//! 2. The page derives ClientKey from the password (PBKDF2-HMAC-SHA-256, as the utility does;
//!    WebCrypto has both) and sends `ClientProof` over [`login_message`] with its own nonce
//!    (`POST /api/v1/session`). The module checks the proof within the module-wide guessing
//!    budget, recovers ClientKey, and answers with a session id and its
//!    [`login_signature`] (the page knows the module, not a forger, answered).
//! 3. Both sides derive the [`session_key`] from ClientKey and the two nonces. The page keeps
//!    it in the tab's memory (never in a cookie or storage another origin could reach) and
//!    signs each state-changing request with [`request_signature`]: an HMAC over the method,
//!    the path with its query, a counter and the body. The module accepts a counter only if it
//!    is above the last one it accepted in that session, so a recorded request cannot be
//!    replayed, and an altered one does not verify.
//! 4. A new password crosses the wire sealed, as discovery seals it: the module makes an
//!    ephemeral X25519 key for the session and proves it with [`agreement_proof`] (a page knows
//!    the key is the module's); the page seals the new credential (never the password) with
//!    [`crate::auth::seal`] under the key both derive, [`PASSWORD_SEAL_LABEL`] and the
//!    module's public key as context. A sniffer who knows the old password (the factory one is
//!    public) still cannot unseal it.

use crate::auth::{hmac, KEY_LEN, NONCE_LEN};

/// The context's domain tag of a new credential sealed by a page (the module's public key
/// follows). Each label here is a domain tag (`crate::domain_tag!`: its length, then its text);
/// docs/web.md writes it tag("...").
pub const PASSWORD_SEAL_LABEL: &[u8] = crate::domain_tag!(b"RDAQ web new credential");

/// The context's domain tag of MQTT's credentials sealed by a client (the module's public key
/// follows), as a new password is sealed ([`PASSWORD_SEAL_LABEL`]).
pub const MQTT_CREDENTIALS_LABEL: &[u8] = crate::domain_tag!(b"RDAQ web mqtt credentials");
/// Domain tag of the binding of MQTT's credentials to the broker they were stored for (its
/// address, port, host name and CA certificate: `remodaq_shared::mqtt::binding`).
pub const MQTT_BINDING_LABEL: &[u8] = crate::domain_tag!(b"RDAQ mqtt binding");
/// The longest MQTT user name and password, bytes.
pub const MQTT_USER_MAX: usize = 32;
/// See [`MQTT_USER_MAX`].
pub const MQTT_PASSWORD_MAX: usize = 64;
/// Bytes of MQTT's credentials as sealed: the user name's length, the name padded with zeros to
/// [`MQTT_USER_MAX`], the password's length, the password padded to [`MQTT_PASSWORD_MAX`].
pub const MQTT_CREDENTIALS_LEN: usize = 2 + MQTT_USER_MAX + MQTT_PASSWORD_MAX;

/// MQTT's credentials as sealed ([`MQTT_CREDENTIALS_LEN`]); `None` if one is too long.
pub fn mqtt_credentials(user: &str, password: &str) -> Option<[u8; MQTT_CREDENTIALS_LEN]> {
    let mut out = [0u8; MQTT_CREDENTIALS_LEN];
    let (u, p) = out.split_at_mut(1 + MQTT_USER_MAX);
    u[0] = user.len() as u8;
    u.get_mut(1..1 + user.len())?.copy_from_slice(user.as_bytes());
    p[0] = password.len() as u8;
    p.get_mut(1..1 + password.len())?.copy_from_slice(password.as_bytes());
    Some(out)
}

/// The user name and password of [`mqtt_credentials`]; `None` if they are not such bytes.
pub fn mqtt_credentials_of(bytes: &[u8; MQTT_CREDENTIALS_LEN]) -> Option<(&str, &str)> {
    let (u, p) = bytes.split_at(1 + MQTT_USER_MAX);
    let user = u.get(1..1 + usize::from(u[0]))?;
    let password = p.get(1..1 + usize::from(p[0]))?;
    Some((core::str::from_utf8(user).ok()?, core::str::from_utf8(password).ok()?))
}

/// HMAC(session key, tag("RDAQ web agreement") || the module's ephemeral public key): signs the
/// key the module offers a session for a password change.
pub fn agreement_proof(session_key: &[u8; KEY_LEN], public: &[u8; KEY_LEN]) -> [u8; KEY_LEN] {
    hmac(session_key, &[AGREEMENT_LABEL, public])
}

/// Domain tag of the proof of the module's key for a password change.
pub const AGREEMENT_LABEL: &[u8] = crate::domain_tag!(b"RDAQ web agreement");
/// Domain tag of a login's AuthMessage (and of the module's signature of the login, which
/// covers the AuthMessage and the session id, under the ServerKey).
pub const LOGIN_LABEL: &[u8] = crate::domain_tag!(b"RDAQ web login");
/// Domain tag of the session key's derivation.
pub const SESSION_LABEL: &[u8] = crate::domain_tag!(b"RDAQ web session");
/// Domain tag of a signed request.
pub const REQUEST_LABEL: &[u8] = crate::domain_tag!(b"RDAQ web request\n");

/// Bytes of a session id.
pub const SESSION_ID_LEN: usize = 8;

/// Firmware bytes in one chunk of an upload through the web console (`PUT
/// /api/v1/firmware/{offset}`): with a browser's request head, within the module's 1536-byte
/// request buffer.
pub const FIRMWARE_CHUNK: usize = 512;

/// The request header that names the session (16 hex digits).
pub const HEADER_SESSION: &str = "X-RDAQ-Session";
/// The request header with the request's counter (decimal, above the session's last one).
pub const HEADER_COUNTER: &str = "X-RDAQ-Counter";
/// The request header with [`request_signature`] (64 hex digits).
pub const HEADER_SIGNATURE: &str = "X-RDAQ-Signature";

/// The AuthMessage of a login, in parts: a label, the module's MAC (a proof made for one
/// module is worth nothing on another), the module's nonce, the page's nonce.
pub fn login_message<'a>(
    mac: &'a [u8; 6],
    module_nonce: &'a [u8; NONCE_LEN],
    page_nonce: &'a [u8; NONCE_LEN],
) -> [&'a [u8]; 4] {
    [LOGIN_LABEL, mac, module_nonce, page_nonce]
}

/// The module's signature of a successful login: HMAC(ServerKey, AuthMessage || session id).
pub fn login_signature(
    server_key: &[u8; KEY_LEN],
    message: &[&[u8]; 4],
    session: &[u8; SESSION_ID_LEN],
) -> [u8; KEY_LEN] {
    hmac(server_key, &[message[0], message[1], message[2], message[3], session])
}

/// The session's key: HMAC(ClientKey, tag("RDAQ web session") || module nonce || page nonce). Only
/// the page (from the password) and the module (from the proof) know ClientKey.
pub fn session_key(
    client_key: &[u8; KEY_LEN],
    module_nonce: &[u8; NONCE_LEN],
    page_nonce: &[u8; NONCE_LEN],
) -> [u8; KEY_LEN] {
    hmac(client_key, &[SESSION_LABEL, module_nonce, page_nonce])
}

/// The signature of a state-changing request: HMAC(session key, tag("RDAQ web request\n") ||
/// METHOD || "\n" || path || "\n" || counter in decimal || "\n" || body), where `path` is the
/// request target as sent (path and query).
pub fn request_signature(key: &[u8; KEY_LEN], method: &str, path: &str, counter: u64, body: &[u8]) -> [u8; KEY_LEN] {
    let mut digits = [0u8; 20];
    let counter = decimal(counter, &mut digits);
    hmac(key, &[REQUEST_LABEL, method.as_bytes(), b"\n", path.as_bytes(), b"\n", counter, b"\n", body])
}

/// Bytes of [`Login::body`]: `{"nonce":"..","page_nonce":"..","proof":".."}`.
pub const LOGIN_BODY_LEN: usize = 10 + 2 * NONCE_LEN + 16 + 2 * NONCE_LEN + 11 + 2 * KEY_LEN + 2;

/// The page's side of a login (docs/web.md) as a PC program makes it: the proof for the
/// module's challenge, then the session's key once the module's answer is signed with the
/// password's ServerKey (a host without the password's keys cannot pose as the module).
#[cfg(any(test, feature = "client"))]
pub struct Login {
    client_key: [u8; KEY_LEN],
    server_key: [u8; KEY_LEN],
    mac: [u8; 6],
    nonce: [u8; NONCE_LEN],
    page_nonce: [u8; NONCE_LEN],
    proof: [u8; KEY_LEN],
}

#[cfg(any(test, feature = "client"))]
impl Login {
    /// The login with `password` to the module `mac` that sent the challenge (`salt`,
    /// `iterations`, `nonce`); `page_nonce` random.
    pub fn new(
        password: &[u8],
        challenge: (&[u8; 16], u32, [u8; NONCE_LEN]),
        mac: [u8; 6],
        page_nonce: [u8; NONCE_LEN],
    ) -> Self {
        let (salt, iterations, nonce) = challenge;
        let (client_key, credential) = crate::auth::derive(password, salt, iterations);
        let proof = crate::auth::client_proof(&client_key, &login_message(&mac, &nonce, &page_nonce));
        Self { client_key, server_key: credential.server_key, mac, nonce, page_nonce, proof }
    }

    /// The body of `POST /api/v1/session`.
    pub fn body<'a>(&self, out: &'a mut [u8; LOGIN_BODY_LEN]) -> &'a str {
        let mut at = 0;
        let mut put = |text: &[u8]| {
            out[at..at + text.len()].copy_from_slice(text);
            at += text.len();
        };
        let (mut n, mut pn, mut p) = ([0u8; 2 * NONCE_LEN], [0u8; 2 * NONCE_LEN], [0u8; 2 * KEY_LEN]);
        put(b"{\"nonce\":\"");
        put(hex(&self.nonce, &mut n).unwrap_or("").as_bytes());
        put(b"\",\"page_nonce\":\"");
        put(hex(&self.page_nonce, &mut pn).unwrap_or("").as_bytes());
        put(b"\",\"proof\":\"");
        put(hex(&self.proof, &mut p).unwrap_or("").as_bytes());
        put(b"\"}");
        core::str::from_utf8(&out[..]).unwrap_or("")
    }

    /// The session's key when `signature` is the module's of this login and session `id`;
    /// `None` when it is not (not the module, or not this password).
    pub fn session_key(&self, id: &[u8; SESSION_ID_LEN], signature: &[u8; KEY_LEN]) -> Option<[u8; KEY_LEN]> {
        let message = login_message(&self.mac, &self.nonce, &self.page_nonce);
        let expected = login_signature(&self.server_key, &message, id);
        crate::auth::same(&expected, signature).then(|| session_key(&self.client_key, &self.nonce, &self.page_nonce))
    }
}

/// `n` in decimal, in `buf`.
fn decimal(mut n: u64, buf: &mut [u8; 20]) -> &[u8] {
    let mut at = buf.len();
    loop {
        at -= 1;
        buf[at] = b'0' + (n % 10) as u8;
        n /= 10;
        if n == 0 {
            return &buf[at..];
        }
    }
}

/// Lowercase hex of `bytes` into `out` (twice as long); `None` if `out` is too short.
pub fn hex<'a>(bytes: &[u8], out: &'a mut [u8]) -> Option<&'a str> {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let out = out.get_mut(..bytes.len() * 2)?;
    for (pair, b) in out.chunks_exact_mut(2).zip(bytes) {
        pair[0] = DIGITS[usize::from(b >> 4)];
        pair[1] = DIGITS[usize::from(b & 15)];
    }
    core::str::from_utf8(out).ok()
}

/// The bytes of `text`, exactly `N` of them in hex (either case); `None` otherwise.
pub fn unhex<const N: usize>(text: &str) -> Option<[u8; N]> {
    let text = text.as_bytes();
    if text.len() != 2 * N {
        return None;
    }
    let nibble = |c: u8| (c as char).to_digit(16).map(|d| d as u8);
    let mut out = [0u8; N];
    for (o, pair) in out.iter_mut().zip(text.chunks_exact(2)) {
        *o = nibble(pair[0])? << 4 | nibble(pair[1])?;
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The canonical form, written out: its HMAC under the key 00 01 .. 1f was computed
    /// independently with Python's `hmac` (`hmac.new(bytes(range(32)), b"\x11RDAQ web
    /// request\nPUT\n/api/v1/do/0?x=1\n42\n{\"on\":true}", "sha256").hexdigest()`: the domain
    /// tag's length byte, 17, then the label).
    #[test]
    fn request_signature_is_the_documented_hmac() {
        let key: [u8; 32] = core::array::from_fn(|i| i as u8);
        let expected: [u8; 32] =
            unhex("ceb9b08e80757b9fddbca501018dd4e4695fe33005480973fd7dd202d695d6a4").unwrap_or([0; 32]);
        let got = request_signature(&key, "PUT", "/api/v1/do/0?x=1", 42, br#"{"on":true}"#);
        assert_eq!(got, expected);
        // Any part changed changes it.
        assert_ne!(request_signature(&key, "POST", "/api/v1/do/0?x=1", 42, br#"{"on":true}"#), got);
        assert_ne!(request_signature(&key, "PUT", "/api/v1/do/1?x=1", 42, br#"{"on":true}"#), got);
        assert_ne!(request_signature(&key, "PUT", "/api/v1/do/0?x=1", 43, br#"{"on":true}"#), got);
        assert_ne!(request_signature(&key, "PUT", "/api/v1/do/0?x=1", 42, br#"{"on":false}"#), got);
    }

    /// A whole login computed independently with Python's `hashlib` and `hmac` (docs/web.md's
    /// recipe: password "correct horse battery", salt 00..0f, 4096 iterations, MAC
    /// 02:00:00:83:50:01, module nonce a0..af, page nonce 10..1f, session id 01..08, each label
    /// a domain tag: its length in a byte, then its text); the same
    /// values check the page's JavaScript (`services/web/web/test/auth.test.js`).
    #[test]
    fn a_login_computed_elsewhere_verifies() {
        use crate::auth::{server_signature, verify_proof};
        let stored: [u8; 32] =
            unhex("0d2391706e1d354c401d3128e412f6d32992a0b82df02f232d9d3d4be5545653").unwrap_or([0; 32]);
        let server: [u8; 32] =
            unhex("f612eb7e77fbcef0ad0c1f5dae455790c814b1de2fa477e0e584090eb6da677d").unwrap_or([0; 32]);
        let proof: [u8; 32] =
            unhex("7a3e1ebd5d67c927c6debfa2d27218b75556031993e96cc595fb7a3a600b14ab").unwrap_or([0; 32]);
        let mac = [0x02, 0, 0, 0x83, 0x50, 1];
        let module_nonce: [u8; 16] = core::array::from_fn(|i| 0xA0 + i as u8);
        let page_nonce: [u8; 16] = core::array::from_fn(|i| 0x10 + i as u8);
        let message = login_message(&mac, &module_nonce, &page_nonce);
        let client_key = verify_proof(&stored, &message, &proof).expect("the proof verifies");
        assert_eq!(
            session_key(&client_key, &module_nonce, &page_nonce),
            unhex::<32>("d6d8ccb09cca07a18fc54cbddaf738b925162097f2bbfa5e93c4d13fbbd0f5c8").unwrap_or([0; 32])
        );
        let session = [1, 2, 3, 4, 5, 6, 7, 8];
        let signature = login_signature(&server, &message, &session);
        assert_eq!(
            signature,
            unhex::<32>("976a80013e4a26e292344d774f87d908cf31003920ed2039ff0f7070ec3e2564").unwrap_or([0; 32])
        );
        assert_eq!(signature, server_signature(&server, &[message[0], message[1], message[2], message[3], &session]));
        // The PC's side (`Login`) makes the same proof and, from this signature, the same key.
        let salt: [u8; 16] = core::array::from_fn(|i| i as u8);
        let login = Login::new(b"correct horse battery", (&salt, 4096, module_nonce), mac, page_nonce);
        let mut body = [0u8; LOGIN_BODY_LEN];
        let body = login.body(&mut body);
        assert!(
            body.starts_with(r#"{"nonce":"a0a1a2"#)
                && body.ends_with(r#"","proof":"7a3e1ebd5d67c927c6debfa2d27218b75556031993e96cc595fb7a3a600b14ab"}"#),
            "{body}"
        );
        assert_eq!(login.session_key(&session, &signature), Some(session_key(&client_key, &module_nonce, &page_nonce)));
        let mut forged = signature;
        forged[0] ^= 1;
        assert_eq!(login.session_key(&session, &forged), None, "not signed with this password's keys");
    }

    /// A page's seal of a new credential and the proof of the module's key, computed
    /// independently with Python's `hmac` (shared secret 00..1f, the module's key 42h x 32, the
    /// credential's bytes 100..183, session key 07h x 32); the same values check the page's
    /// JavaScript (`services/web/web/test/auth.test.js`).
    #[test]
    fn a_sealed_password_computed_elsewhere() {
        let shared: [u8; 32] = core::array::from_fn(|i| i as u8);
        let public = [0x42; 32];
        let mut data: [u8; 84] = core::array::from_fn(|i| 100 + i as u8);
        crate::auth::seal(&shared, &[PASSWORD_SEAL_LABEL, &public], &mut data);
        let expected: [u8; 84] = unhex(
            "bf5f16125ed76787080499b7ca80eab569c3df1663acef47bc0667389ac70dc28d8bfa835024675d9934790d00d54347\
             c35ca4a6f70ec1f173fc61b74d4721264776de1a8bb67613bc19ab2db61ee4c7d0b9fdfb",
        )
        .unwrap_or([0; 84]);
        assert_eq!(data, expected);
        assert_eq!(
            agreement_proof(&[7; 32], &public),
            unhex::<32>("ec1fb2129c11442deaef2821725e567a2db40a30cf03e973a7a098c54120ff53").unwrap_or([0; 32])
        );
    }

    #[test]
    fn decimal_and_hex() {
        let mut buf = [0u8; 20];
        assert_eq!(decimal(0, &mut buf), b"0");
        assert_eq!(decimal(u64::MAX, &mut buf), b"18446744073709551615");
        let mut out = [0u8; 8];
        assert_eq!(hex(&[0x00, 0xab, 0x1f], &mut out), Some("00ab1f"));
        assert_eq!(hex(&[0; 5], &mut out), None);
        assert_eq!(unhex::<3>("00AB1f"), Some([0x00, 0xab, 0x1f]));
        assert_eq!(unhex::<3>("00ab1"), None);
        assert_eq!(unhex::<3>("00ab1g"), None);
        assert_eq!(unhex::<1>("+f"), None);
    }
}
