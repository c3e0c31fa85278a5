//! The module's web console API from a PC program (docs/web.md, docs/openapi.yaml): a login as
//! the console's page makes it (no password on the wire: a proof over the module's challenge,
//! and the module's signature of its answer checked, so a host that does not know the
//! password's keys cannot pose as the module), then signed requests. What `remodaq mqtt` uses
//! for MQTT's settings (docs/mqtt.md), which only the web API carries (they do not fit a
//! discovery datagram).

use std::net::SocketAddr;
use std::time::Duration;

use remodaq_protocol::auth::{KEY_LEN, NONCE_LEN};
use remodaq_protocol::web::{hex, request_signature, unhex, Login, LOGIN_BODY_LEN, SESSION_ID_LEN};
use serde::{Deserialize, Serialize};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use crate::Error;

/// How long one request may take, connection included.
const TIMEOUT: Duration = Duration::from_secs(10);
/// The longest answer read.
const MAX_ANSWER: usize = 64 * 1024;

/// An answer: its status and body.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Answer {
    /// The HTTP status.
    pub status: u16,
    /// The body (JSON, or empty).
    pub body: String,
}

impl Answer {
    /// The module's `error` (and `field`) of a refusal, as a sentence.
    fn reason(&self) -> String {
        let parsed: Option<serde_json::Value> = serde_json::from_str(&self.body).ok();
        let text = |name: &str| parsed.as_ref().and_then(|v| v.get(name)).and_then(|v| v.as_str()).map(str::to_owned);
        match (text("error"), text("field")) {
            (Some(error), Some(field)) => format!("{error} ({field}; HTTP {})", self.status),
            (Some(error), None) => format!("{error} (HTTP {})", self.status),
            _ => format!("HTTP {}", self.status),
        }
    }
}

/// One HTTP/1.1 request to the console at `to`; the answer.
async fn exchange(
    to: SocketAddr,
    method: &str,
    target: &str,
    headers: &[(&str, String)],
    body: &str,
) -> Result<Answer, Error> {
    let send = async {
        let mut stream = TcpStream::connect(to).await.map_err(|e| Error::Other(format!("{to}: {e}")))?;
        let mut text = format!(
            "{method} {target} HTTP/1.1\r\nHost: {to}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n",
            body.len()
        );
        for (name, value) in headers {
            text += &format!("{name}: {value}\r\n");
        }
        text += "\r\n";
        text += body;
        stream.write_all(text.as_bytes()).await.map_err(|e| Error::Other(format!("{to}: {e}")))?;
        let mut answer = Vec::new();
        (&mut stream)
            .take(MAX_ANSWER as u64)
            .read_to_end(&mut answer)
            .await
            .map_err(|e| Error::Other(format!("{to}: {e}")))?;
        let text = String::from_utf8_lossy(&answer).into_owned();
        let status = text.split(' ').nth(1).and_then(|c| c.parse().ok());
        let (_, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
        match status {
            Some(status) if text.starts_with("HTTP/1.") => Ok(Answer { status, body: body.to_owned() }),
            _ => Err(Error::Reply(format!("{to}: not an HTTP answer"))),
        }
    };
    tokio::time::timeout(TIMEOUT, send).await.map_err(|_| Error::Timeout(format!("{to}: no answer in {TIMEOUT:?}")))?
}

/// A logged-in session of the web console: its requests are signed.
pub struct Session {
    to: SocketAddr,
    id: [u8; SESSION_ID_LEN],
    key: [u8; KEY_LEN],
    counter: u64,
}

#[derive(Deserialize)]
struct Challenge {
    salt: String,
    iterations: u32,
    nonce: String,
}

#[derive(Deserialize)]
struct Identity {
    mac: String,
}

#[derive(Deserialize)]
struct LoggedIn {
    session: String,
    signature: String,
}

fn bytes<const N: usize>(text: &str, what: &str) -> Result<[u8; N], Error> {
    unhex(text).ok_or_else(|| Error::Reply(format!("the module's {what} is not {} hex digits", 2 * N)))
}

fn json<'a, T: Deserialize<'a>>(answer: &'a Answer, what: &str) -> Result<T, Error> {
    serde_json::from_str(&answer.body).map_err(|e| Error::Reply(format!("{what}: {e}")))
}

impl Session {
    /// Logs in to the console at `to` with `password` as its page does (docs/web.md).
    pub async fn log_in(to: SocketAddr, password: &str) -> Result<Self, Error> {
        let challenge = exchange(to, "POST", "/api/v1/session/challenge", &[], "").await?;
        if challenge.status != 200 {
            return Err(Error::Refused(format!("login: {}", challenge.reason())));
        }
        let challenge: Challenge = json(&challenge, "the login challenge")?;
        if !(4096..=10_000_000).contains(&challenge.iterations) {
            return Err(Error::Reply(format!("the module asks for {} iterations", challenge.iterations)));
        }
        let identity = exchange(to, "GET", "/api/v1/identity", &[], "").await?;
        let mac: [u8; 6] = bytes(&json::<Identity>(&identity, "the identity")?.mac, "MAC")?;
        let salt: [u8; 16] = bytes(&challenge.salt, "salt")?;
        let nonce: [u8; NONCE_LEN] = bytes(&challenge.nonce, "nonce")?;
        let mut page_nonce = [0u8; NONCE_LEN];
        getrandom::fill(&mut page_nonce).map_err(|e| Error::Other(format!("no random numbers: {e}")))?;
        let login = Login::new(password.as_bytes(), (&salt, challenge.iterations, nonce), mac, page_nonce);
        let mut body = [0u8; LOGIN_BODY_LEN];
        let answer = exchange(to, "POST", "/api/v1/session", &[], login.body(&mut body)).await?;
        match answer.status {
            200 => {}
            401 => return Err(Error::Refused("wrong password".into())),
            _ => return Err(Error::Refused(format!("login: {}", answer.reason()))),
        }
        let logged_in: LoggedIn = json(&answer, "the login's answer")?;
        let id: [u8; SESSION_ID_LEN] = bytes(&logged_in.session, "session id")?;
        let signature: [u8; KEY_LEN] = bytes(&logged_in.signature, "signature")?;
        let Some(key) = login.session_key(&id, &signature) else {
            return Err(Error::Refused("the answer is not signed with this password's keys: not the module".into()));
        };
        Ok(Self { to, id, key, counter: 0 })
    }

    /// A signed request; its answer.
    pub async fn request(&mut self, method: &str, target: &str, body: &str) -> Result<Answer, Error> {
        self.counter += 1;
        let signature = request_signature(&self.key, method, target, self.counter, body.as_bytes());
        let (mut id, mut sig) = ([0u8; 16], [0u8; 64]);
        let headers = [
            ("X-RDAQ-Session", hex(&self.id, &mut id).unwrap_or("").to_owned()),
            ("X-RDAQ-Counter", self.counter.to_string()),
            ("X-RDAQ-Signature", hex(&signature, &mut sig).unwrap_or("").to_owned()),
        ];
        exchange(self.to, method, target, &headers, body).await
    }
}

/// MQTT's settings as the API shows and takes them (`/api/v1/mqtt`, docs/mqtt.md).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct MqttSettings {
    /// Connect to the broker.
    pub on: bool,
    /// The broker's IPv4 address.
    pub broker: String,
    /// The broker's host name (TLS checks its certificate against it).
    pub host: String,
    /// The broker's port.
    pub port: u16,
    /// The client identifier (empty: `remodaq-<mac>`).
    pub client_id: String,
    /// TLS to the broker.
    pub tls: bool,
    /// The topics' prefix (empty: `remodaq/<model>/<mac>`).
    pub prefix: String,
    /// Each point at least once per this, ms.
    pub period_ms: u32,
    /// 0 or 1.
    pub qos: u8,
    /// The 8318's deadbands, thousandths of each channel's unit.
    pub deadbands: Vec<u32>,
    /// The 8350's points on any change.
    pub on_change: bool,
    /// The 8350 takes output commands.
    pub commands: bool,
    /// The time server (SNTP): `a.b.c.d[:port]`, empty for none.
    #[serde(default)]
    pub sntp: String,
    /// A CA certificate is stored (shown, never sent back).
    #[serde(default, skip_serializing)]
    pub ca: bool,
    /// A user name and password for the broker are stored (shown, never sent back).
    #[serde(default, skip_serializing)]
    pub credentials: bool,
}

impl Session {
    /// MQTT's settings.
    pub async fn mqtt(&mut self) -> Result<MqttSettings, Error> {
        let answer = self.request("GET", "/api/v1/mqtt", "").await?;
        match answer.status {
            200 => json(&answer, "MQTT's settings"),
            404 => Err(Error::Other("this module has no MQTT (docs/mqtt.md)".into())),
            _ => Err(Error::Refused(answer.reason())),
        }
    }

    /// Stores MQTT's settings (in force at once).
    pub async fn set_mqtt(&mut self, settings: &MqttSettings) -> Result<(), Error> {
        let body = serde_json::to_string(settings).map_err(|e| Error::Other(e.to_string()))?;
        let answer = self.request("PUT", "/api/v1/mqtt", &body).await?;
        stored(&answer)
    }

    /// Stores the CA certificate the broker's chain must lead to: `pem`, one certificate (a PEM
    /// file's text; its lines are joined by spaces for the API), or "" for none.
    pub async fn set_mqtt_ca(&mut self, pem: &str) -> Result<(), Error> {
        let joined = pem.split_whitespace().collect::<Vec<_>>().join(" ");
        let body = serde_json::json!({ "pem": joined }).to_string();
        let answer = self.request("PUT", "/api/v1/mqtt/ca", &body).await?;
        stored(&answer)
    }

    /// Stores the broker's user name and password, sealed for a key the module offers this
    /// session (`POST /api/v1/password/key`, its proof checked): never in clear on the wire.
    pub async fn set_mqtt_credentials(&mut self, user: &str, password: &str) -> Result<(), Error> {
        use remodaq_protocol::auth::{seal, x25519, BASE_POINT};
        use remodaq_protocol::web::{agreement_proof, mqtt_credentials, MQTT_CREDENTIALS_LABEL};
        let mut sealed = mqtt_credentials(user, password)
            .ok_or_else(|| Error::Other("a user name of at most 32 bytes and a password of at most 64".into()))?;
        #[derive(Deserialize)]
        struct Offer {
            public: String,
            proof: String,
        }
        let answer = self.request("POST", "/api/v1/password/key", "").await?;
        if answer.status != 200 {
            return Err(Error::Refused(answer.reason()));
        }
        let offer: Offer = json(&answer, "the module's key")?;
        let module: [u8; KEY_LEN] = bytes(&offer.public, "the module's key")?;
        if bytes::<KEY_LEN>(&offer.proof, "its proof")? != agreement_proof(&self.key, &module) {
            return Err(Error::Other("the module's key is not signed by this session: not sent".into()));
        }
        let mut secret = [0u8; KEY_LEN];
        getrandom::fill(&mut secret).map_err(|e| Error::Other(format!("no random numbers: {e}")))?;
        seal(&x25519(&secret, &module), &[MQTT_CREDENTIALS_LABEL, &module], &mut sealed);
        let (mut m, mut p, mut s) = ([0u8; 2 * KEY_LEN], [0u8; 2 * KEY_LEN], [0u8; 2 * 98]);
        let body = serde_json::json!({
            "module": hex(&module, &mut m).unwrap_or(""),
            "public": hex(&x25519(&secret, &BASE_POINT), &mut p).unwrap_or(""),
            "sealed": hex(&sealed, &mut s).unwrap_or(""),
        })
        .to_string();
        let answer = self.request("PUT", "/api/v1/mqtt/credentials", &body).await?;
        stored(&answer)
    }
}

/// A change's answer: stored (204), refused with its reason.
fn stored(answer: &Answer) -> Result<(), Error> {
    match answer.status {
        204 => Ok(()),
        404 => Err(Error::Other("this module has no MQTT (docs/mqtt.md)".into())),
        422 | 400 | 409 => Err(Error::Other(format!("refused: {}", answer.reason()))),
        _ => Err(Error::Refused(answer.reason())),
    }
}

/// A certificate file's PEM: the file itself when it is PEM, DER made PEM otherwise.
pub fn pem_of_file(file: &str) -> Result<String, Error> {
    let bytes = std::fs::read(file).map_err(|e| Error::Other(format!("{file}: {e}")))?;
    if let Ok(text) = std::str::from_utf8(&bytes) {
        if text.contains("-----BEGIN CERTIFICATE-----") {
            return Ok(text.to_owned());
        }
    }
    if bytes.first() != Some(&0x30) {
        return Err(Error::Other(format!("{file}: neither a PEM nor a DER certificate")));
    }
    const DIGITS: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut base64 = String::new();
    for chunk in bytes.chunks(3) {
        let n = chunk.iter().enumerate().fold(0u32, |n, (i, b)| n | u32::from(*b) << (16 - 8 * i));
        for i in 0..4 {
            base64.push(if i <= chunk.len() { DIGITS[(n >> (18 - 6 * i) & 63) as usize] as char } else { '=' });
        }
    }
    Ok(format!("-----BEGIN CERTIFICATE-----\n{base64}\n-----END CERTIFICATE-----\n"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A DER file made PEM (RFC 4648's base64: 30 03 02 01 01 is "MAMCAQE="); a PEM file kept.
    #[test]
    fn a_certificate_file_as_pem() {
        let dir = std::env::temp_dir().join(format!("rdaq-pem-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("a directory");
        let der = dir.join("ca.der");
        std::fs::write(&der, [0x30, 3, 2, 1, 1]).expect("write");
        let pem = pem_of_file(&der.display().to_string()).expect("a PEM");
        assert_eq!(pem, "-----BEGIN CERTIFICATE-----\nMAMCAQE=\n-----END CERTIFICATE-----\n");
        let file = dir.join("ca.pem");
        std::fs::write(&file, &pem).expect("write");
        assert_eq!(pem_of_file(&file.display().to_string()).expect("a PEM"), pem);
        std::fs::write(&file, "junk").expect("write");
        assert!(pem_of_file(&file.display().to_string()).is_err());
        let _ = std::fs::remove_dir_all(dir);
    }
}
