//! An HTTP client of the web console's API for end-to-end tests (docs/web.md): raw requests,
//! and a login computed on the PC's side as a page computes it.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

use remodaq_protocol::auth::{derive, seal, x25519, BASE_POINT, CREDENTIAL_LEN, KEY_LEN, NONCE_LEN};
use remodaq_protocol::web::{
    agreement_proof, hex, request_signature, unhex, Login, LOGIN_BODY_LEN, PASSWORD_SEAL_LABEL, SESSION_ID_LEN,
};

/// An HTTP answer: status, headers, body.
pub struct Answer {
    /// The status code (0: no answer).
    pub status: u16,
    /// The header lines as sent, after the status line.
    pub head: String,
    /// The body (as text: a gzip-compressed page's bytes come out mangled).
    pub body: String,
}

impl Answer {
    /// The value of header `name` (its first line; the name in any case).
    pub fn header(&self, name: &str) -> Option<&str> {
        self.head.lines().find_map(|line| {
            let (n, v) = line.split_once(':')?;
            n.eq_ignore_ascii_case(name).then(|| v.trim())
        })
    }
}

/// Sends `request` (the whole text) and reads the answer until the module closes. A refused
/// connection is tried again for up to 5 s: a module just restarted opens its web port last.
pub fn send_raw(web: SocketAddr, request: &[u8]) -> Answer {
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    let mut s = loop {
        match TcpStream::connect(web) {
            Ok(s) => break s,
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused && std::time::Instant::now() < deadline => {
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(e) => panic!("connect: {e:?}"),
        }
    };
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let _ = s.write_all(request);
    let mut text = Vec::new();
    let _ = s.read_to_end(&mut text);
    let text = String::from_utf8_lossy(&text).into_owned();
    let status = text.split(' ').nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    let head = head.split_once("\r\n").map_or("", |(_, h)| h).to_string();
    Answer { status, head, body: body.to_string() }
}

/// Sends one request with a `Host` (the module's address) and a `Content-Length` header.
pub fn request(web: SocketAddr, method: &str, target: &str, headers: &[(&str, String)], body: &str) -> Answer {
    request_to_host(web, &web.to_string(), method, target, headers, body)
}

/// [`request`], saying `host` as the `Host`.
pub fn request_to_host(
    web: SocketAddr,
    host: &str,
    method: &str,
    target: &str,
    headers: &[(&str, String)],
    body: &str,
) -> Answer {
    let mut text = format!("{method} {target} HTTP/1.1\r\nHost: {host}\r\nContent-Length: {}\r\n", body.len());
    for (name, value) in headers {
        text += &format!("{name}: {value}\r\n");
    }
    text += "\r\n";
    text += body;
    send_raw(web, text.as_bytes())
}

/// The value of `"field":"..."` in a JSON text.
pub fn field<'a>(json: &'a str, name: &str) -> &'a str {
    let key = format!("\"{name}\":\"");
    json.split(&key).nth(1).and_then(|rest| rest.split('"').next()).unwrap_or("")
}

/// A number `"name":N` in a JSON text.
pub fn number(json: &str, name: &str) -> Option<f64> {
    json.split(&format!("\"{name}\":")).nth(1)?.split([',', '}']).next()?.parse().ok()
}

/// A logged-in page: its session and key, and its next counter.
pub struct Page {
    session: [u8; SESSION_ID_LEN],
    key: [u8; KEY_LEN],
    /// The counter of the last signed request.
    pub counter: u64,
}

impl Page {
    /// The headers of a signed request.
    pub fn sign(&mut self, method: &str, target: &str, body: &str) -> Vec<(&'static str, String)> {
        self.counter += 1;
        let signature = request_signature(&self.key, method, target, self.counter, body.as_bytes());
        let (mut id, mut sig) = ([0u8; 16], [0u8; 64]);
        vec![
            ("X-RDAQ-Session", hex(&self.session, &mut id).unwrap_or("").to_string()),
            ("X-RDAQ-Counter", self.counter.to_string()),
            ("X-RDAQ-Signature", hex(&signature, &mut sig).unwrap_or("").to_string()),
        ]
    }
}

impl Page {
    /// Changes the password as a page does (docs/web.md): the module's ephemeral key, its proof
    /// checked; the new credential (salt `salt`, 4096 iterations) sealed under the agreed key.
    /// The answer to the `PUT`.
    pub fn change_password(&mut self, web: SocketAddr, new: &str, salt: [u8; 16]) -> Answer {
        let module = self.password_key(web);
        self.put_password(web, &module, new, salt)
    }

    /// The module's ephemeral key for a password change (`POST /api/v1/password/key`), its
    /// proof checked against this session's key.
    pub fn password_key(&mut self, web: SocketAddr) -> [u8; KEY_LEN] {
        let offer = request(web, "POST", "/api/v1/password/key", &self.sign("POST", "/api/v1/password/key", ""), "");
        assert_eq!(offer.status, 200, "{}", offer.body);
        let module: [u8; KEY_LEN] = unhex(field(&offer.body, "public")).expect("the module's key");
        let proof: [u8; KEY_LEN] = unhex(field(&offer.body, "proof")).expect("its proof");
        assert_eq!(proof, agreement_proof(&self.key, &module), "the key is signed by this session");
        module
    }

    /// `PUT /api/v1/password`: the new credential sealed for the module's key `module`.
    pub fn put_password(&mut self, web: SocketAddr, module: &[u8; KEY_LEN], new: &str, salt: [u8; 16]) -> Answer {
        let secret = [0x5A; KEY_LEN];
        let (_, credential) = derive(new.as_bytes(), &salt, 4096);
        let mut sealed = credential.encode();
        seal(&x25519(&secret, module), &[PASSWORD_SEAL_LABEL, module], &mut sealed);
        let (mut m, mut p, mut s) = ([0u8; 64], [0u8; 64], [0u8; 2 * CREDENTIAL_LEN]);
        let body = format!(
            "{{\"module\":\"{}\",\"public\":\"{}\",\"sealed\":\"{}\"}}",
            hex(module, &mut m).unwrap_or(""),
            hex(&x25519(&secret, &BASE_POINT), &mut p).unwrap_or(""),
            hex(&sealed, &mut s).unwrap_or("")
        );
        request(web, "PUT", "/api/v1/password", &self.sign("PUT", "/api/v1/password", &body), &body)
    }

    /// `PUT /api/v1/mqtt/credentials`: MQTT's user name and password sealed for a key the module
    /// offers this session (docs/mqtt.md).
    pub fn put_mqtt_credentials(&mut self, web: SocketAddr, user: &str, password: &str) -> Answer {
        use remodaq_protocol::web::{mqtt_credentials, MQTT_CREDENTIALS_LABEL, MQTT_CREDENTIALS_LEN};
        let module = self.password_key(web);
        let secret = [0x6B; KEY_LEN];
        let mut sealed = mqtt_credentials(user, password).expect("short enough");
        seal(&x25519(&secret, &module), &[MQTT_CREDENTIALS_LABEL, &module], &mut sealed);
        let (mut m, mut p, mut s) = ([0u8; 64], [0u8; 64], [0u8; 2 * MQTT_CREDENTIALS_LEN]);
        let body = format!(
            "{{\"module\":\"{}\",\"public\":\"{}\",\"sealed\":\"{}\"}}",
            hex(&module, &mut m).unwrap_or(""),
            hex(&x25519(&secret, &BASE_POINT), &mut p).unwrap_or(""),
            hex(&sealed, &mut s).unwrap_or("")
        );
        let target = "/api/v1/mqtt/credentials";
        request(web, "PUT", target, &self.sign("PUT", target, &body), &body)
    }
}

/// Logs in as a page does (docs/web.md); the answer when it fails.
pub fn log_in(web: SocketAddr, password: &str) -> Result<Page, Answer> {
    let challenge = request(web, "POST", "/api/v1/session/challenge", &[], "");
    assert_eq!(challenge.status, 200, "{}", challenge.body);
    let salt: [u8; 16] = unhex(field(&challenge.body, "salt")).expect("salt");
    let nonce: [u8; NONCE_LEN] = unhex(field(&challenge.body, "nonce")).expect("nonce");
    let iterations: u32 = challenge
        .body
        .split("\"iterations\":")
        .nth(1)
        .and_then(|r| r.split(',').next())
        .and_then(|n| n.parse().ok())
        .expect("iterations");
    let identity = request(web, "GET", "/api/v1/identity", &[], "");
    let mac: [u8; 6] = unhex(field(&identity.body, "mac")).expect("mac");
    let login = Login::new(password.as_bytes(), (&salt, iterations, nonce), mac, [0x42; NONCE_LEN]);
    let mut body = [0u8; LOGIN_BODY_LEN];
    let answer = request(web, "POST", "/api/v1/session", &[], login.body(&mut body));
    if answer.status != 200 {
        return Err(answer);
    }
    let session: [u8; SESSION_ID_LEN] = unhex(field(&answer.body, "session")).expect("session id");
    let signature: [u8; KEY_LEN] = unhex(field(&answer.body, "signature")).expect("signature");
    let key =
        login.session_key(&session, &signature).expect("the module signed its answer with this password's ServerKey");
    Ok(Page { session, key, counter: 0 })
}
