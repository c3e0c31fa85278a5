//! The module's settings that are no registers, in the web console's API (docs/web.md): the
//! network settings, the Modbus write allow-list and the configuration password, as discovery
//! shows and sets them (extensions §4), and the restart that puts new network settings in
//! force. Each change is a
//! signed request of a logged-in session, committed to flash all or nothing as discovery
//! commits it (the old settings stay in force when the flash refuses).

use core::cell::Cell;
use core::fmt::Write as _;
use core::net::Ipv4Addr;
use core::sync::atomic::{AtomicU16, Ordering};

use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, RawMutex};
use embassy_sync::blocking_mutex::Mutex as Blocking;
use embedded_storage_async::nor_flash::NorFlash;
use picoserve::response::StatusCode;
use remodaq_protocol::access::{AllowList, Network, MAX_NETWORKS};
use remodaq_protocol::auth::{seal, Credential, CREDENTIAL_LEN, KEY_LEN};
use remodaq_protocol::net::{parse_ipv4, NetConfig};
use remodaq_protocol::web::{agreement_proof, hex, unhex, PASSWORD_SEAL_LABEL, SESSION_ID_LEN};
use remodaq_shared::offload::{key_pair, x25519};

use crate::service::api::{Answer, Api, Json};
use remodaq_shared::json::Object;
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::{commit_change, CommonSettings as _, SettingsAccess};
use remodaq_shared::net::NETWORK_STORED;

/// The port the console is served on since the start (0 until a board serves it).
static RUNNING_PORT: AtomicU16 = AtomicU16::new(0);

/// Says which port the board serves the console on (the stored one at its start, or the host
/// build's `--http`).
pub fn serving_on(port: u16) {
    RUNNING_PORT.store(port, Ordering::Relaxed);
}

/// The ephemeral X25519 key offered for a password change: its secret, its public key and the
/// session it was offered to. One at a time; used once.
type Agreement = ([u8; KEY_LEN], [u8; KEY_LEN], [u8; SESSION_ID_LEN]);
static AGREEMENT: Blocking<CriticalSectionRawMutex, Cell<Option<Agreement>>> = Blocking::new(Cell::new(None));

/// Why a network body is refused: the field at fault.
#[derive(Debug, PartialEq, Eq)]
pub enum NetworkError {
    /// The body is no JSON object of the four fields.
    NotJson,
    /// This field's value is not usable (an address that is 0.0.0.0, loopback or multicast,
    /// a mask that is not contiguous or leaves fewer than 2 host bits, a port that is 0 or
    /// another service's).
    Field(&'static str),
}

/// The network settings and the console's port of a `PUT /api/v1/network` body, checked as
/// discovery checks them ([`NetConfig::is_valid`]; the console's port neither 0 nor one of the
/// module's other TCP ports), the field at fault named.
pub fn network_of(body: &[u8]) -> Result<(NetConfig, u16), NetworkError> {
    // Every field must be there, of its kind, before any is checked.
    let fields = Object::parse(body).and_then(|o| {
        Some((o.str("ip")?, o.str("mask")?, o.str("gateway")?, o.u16("modbus_port")?, o.u16("http_port")?))
    });
    let Some((ip, mask, gateway, modbus_port, http_port)) = fields else {
        return Err(NetworkError::NotJson);
    };
    let address = |text: &str, field| parse_ipv4(text).ok_or(NetworkError::Field(field));
    let net = NetConfig {
        ip: address(ip, "ip")?,
        mask: address(mask, "mask")?,
        gateway: address(gateway, "gateway")?,
        port: modbus_port,
    };
    if net.is_valid() {
        return match http_port {
            0 | remodaq_protocol::update::PORT => Err(NetworkError::Field("http_port")),
            port if port == net.port => Err(NetworkError::Field("http_port")),
            port => Ok((net, port)),
        };
    }
    // Which of is_valid's conditions failed, in its order.
    let field = if !net.prefix_len().is_some_and(|p| (1..=30).contains(&p)) {
        "mask"
    } else if net.port == 0 || net.port == remodaq_protocol::update::PORT {
        "modbus_port"
    } else {
        "ip"
    };
    Err(NetworkError::Field(field))
}

/// The allow-list of a `PUT /api/v1/access` body (`{"networks": [...]}`, at most
/// [`MAX_NETWORKS`], `a.b.c.d/n` each); `None` when it is not one.
pub fn allow_list_of(body: &[u8]) -> Option<AllowList> {
    let mut nets: heapless::Vec<Network, MAX_NETWORKS> = heapless::Vec::new();
    for text in Object::parse(body)?.strings("networks")? {
        nets.push(text.parse().ok()?).ok()?;
    }
    AllowList::of(&nets)
}

fn write_net(out: &mut Json, net: &NetConfig, http_port: u16) {
    let _ = write!(
        out,
        "{{\"ip\":\"{}\",\"mask\":\"{}\",\"gateway\":\"{}\",\"modbus_port\":{},\"http_port\":{}}}",
        Ipv4Addr::from(net.ip),
        Ipv4Addr::from(net.mask),
        Ipv4Addr::from(net.gateway),
        net.port,
        http_port
    );
}

impl<R: RawMutex, M: RegisterMap + SettingsAccess, F: NorFlash> Api<'_, R, M, F> {
    /// `GET /api/v1/network`: the stored settings (in force after the next start), those in
    /// force now, and whether settings were stored since the start (a restart puts them in
    /// force). Anyone may read them, as discovery's search shows them to anyone.
    pub(super) async fn network(&self, out: &mut Json) -> Answer {
        let (stored, http_port) = {
            let map = self.map.lock().await;
            (map.settings().net(), map.settings().http_port())
        };
        let a = Answer::new(out, StatusCode::OK);
        out.push_str("{\"stored\":");
        write_net(out, &stored, http_port);
        out.push_str(",\"running\":");
        write_net(out, &self.identity.running, RUNNING_PORT.load(Ordering::Relaxed));
        let _ = write!(out, ",\"restart_needed\":{}}}", NETWORK_STORED.load(Ordering::Relaxed));
        a
    }

    /// `PUT /api/v1/network` (signed): stores new network settings, in force after a restart.
    pub(super) async fn set_network(&self, out: &mut Json, body: &[u8]) -> Answer {
        match network_of(body) {
            Ok((net, http_port)) => {
                let answer = self
                    .commit(out, |s| {
                        s.set_net(net);
                        s.set_http_port(http_port);
                    })
                    .await;
                if answer.status == StatusCode::NO_CONTENT {
                    NETWORK_STORED.store(true, Ordering::Relaxed);
                }
                answer
            }
            Err(NetworkError::NotJson) => Answer::error(
                out,
                StatusCode::BAD_REQUEST,
                "expected {ip, mask, gateway, modbus_port, http_port}",
                None,
            ),
            Err(NetworkError::Field(field)) => {
                Answer::error(out, StatusCode::UNPROCESSABLE_ENTITY, "not a usable value", Some(field))
            }
        }
    }

    /// `GET /api/v1/access` (signed: discovery shows the list only with the password).
    pub(super) async fn access(&self, out: &mut Json) -> Answer {
        let list = self.map.lock().await.settings().allow_list();
        let a = Answer::new(out, StatusCode::OK);
        out.push_str("{\"networks\":[");
        for (i, net) in list.iter().enumerate() {
            let _ = write!(out, "{}\"{net}\"", if i > 0 { "," } else { "" });
        }
        out.push_str("]}");
        a
    }

    /// `PUT /api/v1/access` (signed): replaces the Modbus write allow-list.
    pub(super) async fn set_access(&self, out: &mut Json, body: &[u8]) -> Answer {
        match allow_list_of(body) {
            Some(list) => self.commit(out, |s| s.set_allow_list(list)).await,
            None => Answer::error(
                out,
                StatusCode::UNPROCESSABLE_ENTITY,
                "at most 4 networks, a.b.c.d/n each",
                Some("networks"),
            ),
        }
    }

    /// `POST /api/v1/password/key` (signed): a new ephemeral key for this session's password
    /// change, proved with the session key.
    pub(super) fn password_key(&self, out: &mut Json, session: [u8; SESSION_ID_LEN]) -> Answer {
        let Some(session_key) = self.sessions.lock(|s| s.borrow().key(&session)) else {
            return Answer::error(out, StatusCode::UNAUTHORIZED, "no session", None);
        };
        // Made ahead by the offload worker (`remodaq_shared::offload::key_pair`).
        let (secret, public) = key_pair(&(self.now_ms)().to_le_bytes());
        AGREEMENT.lock(|a| a.set(Some((secret, public, session))));
        let (mut key, mut proof) = ([0u8; 2 * KEY_LEN], [0u8; 2 * KEY_LEN]);
        let a = Answer::new(out, StatusCode::OK);
        let _ = write!(
            out,
            "{{\"public\":\"{}\",\"proof\":\"{}\"}}",
            hex(&public, &mut key).unwrap_or(""),
            hex(&agreement_proof(&session_key, &public), &mut proof).unwrap_or("")
        );
        a
    }

    /// `PUT /api/v1/password` (signed): the new credential, sealed under the key agreed with
    /// this session's ephemeral key (used once). Every session ends with the old password.
    pub(super) async fn set_password(&self, out: &mut Json, session: [u8; SESSION_ID_LEN], body: &[u8]) -> Answer {
        let bytes = match unsealed::<CREDENTIAL_LEN>(session, body, PASSWORD_SEAL_LABEL).await {
            Ok(bytes) => bytes,
            Err(why) => return why.answer(out, "the keys are 64 hex digits, the credential 168"),
        };
        let new = Credential::decode(&bytes);
        if !new.is_acceptable() || new.is_factory() {
            return Answer::error(out, StatusCode::UNPROCESSABLE_ENTITY, "not a usable password", Some("sealed"));
        }
        let answer = self.commit(out, |s| s.set_password(new)).await;
        if answer.status == StatusCode::NO_CONTENT {
            remodaq_shared::diagnostics::DIAGNOSTICS.factory_password(false);
            remodaq_shared::info!("web: password changed");
        }
        answer
    }

    /// `POST /api/v1/restart` (signed): the module restarts once this answer is sent and the
    /// connection closed (by this connection's task: see [`super::service::Served`]).
    pub(super) fn restart(&self, out: &mut Json) -> Answer {
        self.restart.set(true);
        Answer::accepted(out)
    }

    async fn commit(&self, out: &mut Json, change: impl FnOnce(&mut M::Settings)) -> Answer {
        committed(out, commit_change(self.map, self.store, change).await)
    }
}

/// Why a sealed secret was not opened.
pub(crate) enum Unsealed {
    /// Not `{module, public, sealed}`.
    NotJson,
    /// Not hex of the right lengths.
    NotHex,
    /// No key was offered to this session, or the secret was sealed for another.
    NoOffer,
}

impl Unsealed {
    /// The answer: 400, or 409 (ask for the module's key first).
    pub(crate) fn answer(self, out: &mut Json, lengths: &'static str) -> Answer {
        match self {
            Unsealed::NotJson => Answer::error(out, StatusCode::BAD_REQUEST, "expected {module, public, sealed}", None),
            Unsealed::NotHex => Answer::error(out, StatusCode::BAD_REQUEST, lengths, None),
            Unsealed::NoOffer => {
                Answer::error(out, StatusCode::CONFLICT, "ask for the module's key first", Some("module"))
            }
        }
    }
}

/// The `N` bytes sealed in `body` (`{module, public, sealed}`) under the key this session was
/// offered (`POST /api/v1/password/key`, used once) and `label`: a new password, or MQTT's
/// credentials.
pub(crate) async fn unsealed<const N: usize>(
    session: [u8; SESSION_ID_LEN],
    body: &[u8],
    label: &[u8],
) -> Result<[u8; N], Unsealed> {
    let o = Object::parse(body).ok_or(Unsealed::NotJson)?;
    let (module, public, sealed) =
        (o.str("module").ok_or(Unsealed::NotJson)?, o.str("public").ok_or(Unsealed::NotJson)?, o.str("sealed"));
    let (Some(sealed_for), Some(public), Some(mut bytes)) =
        (unhex::<KEY_LEN>(module), unhex::<KEY_LEN>(public), unhex::<N>(sealed.ok_or(Unsealed::NotJson)?))
    else {
        return Err(Unsealed::NotHex);
    };
    // Only the key offered to this session, and only for a secret sealed for that very key: one
    // sealed for an earlier key would open to random bytes (a password nobody knows). Another
    // session's request leaves the key in place.
    let offered = AGREEMENT.lock(|a| match a.get() {
        Some((secret, module_public, offered_to)) if offered_to == session && module_public == sealed_for => {
            a.set(None);
            Some((secret, module_public))
        }
        _ => None,
    });
    let (secret, module_public) = offered.ok_or(Unsealed::NoOffer)?;
    // The key agreement by the worker off the main executor (`remodaq_shared::offload`).
    seal(&x25519(&secret, &public).await, &[label, &module_public], &mut bytes);
    Ok(bytes)
}

/// The answer to a settings change once committed, or why not: 204, 429 when the commit budget
/// is spent, 503 when the flash refused.
pub(crate) fn committed(out: &mut Json, result: Result<(), remodaq_shared::settings::StoreError>) -> Answer {
    match result {
        Ok(()) => Answer::no_content(out),
        Err(remodaq_shared::settings::StoreError::Budget) => Answer::error(
            out,
            StatusCode::TOO_MANY_REQUESTS,
            "too many settings changes: the flash commit budget is spent, one more every 15 minutes",
            None,
        ),
        Err(_) => Answer::error(out, StatusCode::SERVICE_UNAVAILABLE, "the settings could not be stored", None),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn network_bodies() {
        let body =
            br#"{"ip":"10.0.5.20","mask":"255.255.0.0","gateway":"10.0.0.1","modbus_port":502,"http_port":8080}"#;
        let net = network_of(body).expect("usable");
        let expected = NetConfig { ip: [10, 0, 5, 20], mask: [255, 255, 0, 0], gateway: [10, 0, 0, 1], port: 502 };
        assert_eq!(net, (expected, 8080));
        let with_ports = |ip: &str, mask: &str, port: u16, http: u16| {
            let body = std::format!(
                r#"{{"ip":"{ip}","mask":"{mask}","gateway":"0.0.0.0","modbus_port":{port},"http_port":{http}}}"#
            );
            network_of(body.as_bytes())
        };
        let with = |ip: &str, mask: &str, port: u16| with_ports(ip, mask, port, 80);
        // The console's port: not 0, not Modbus's, not the update service's (8301).
        for http in [0, 502, 8301] {
            assert_eq!(with_ports("10.0.0.1", "255.0.0.0", 502, http), Err(NetworkError::Field("http_port")), "{http}");
        }
        assert_eq!(with("10.0.0.300", "255.0.0.0", 502), Err(NetworkError::Field("ip")));
        assert_eq!(with("127.0.0.5", "255.0.0.0", 502), Err(NetworkError::Field("ip")));
        assert_eq!(with("224.0.0.1", "255.0.0.0", 502), Err(NetworkError::Field("ip")));
        assert_eq!(with("10.0.0.1", "255.0.255.0", 502), Err(NetworkError::Field("mask")));
        assert_eq!(with("10.0.0.1", "255.255.255.254", 502), Err(NetworkError::Field("mask")));
        assert_eq!(with("10.0.0.1", "255.0.0.0", 0), Err(NetworkError::Field("modbus_port")));
        assert_eq!(with("10.0.0.1", "255.0.0.0", 8301), Err(NetworkError::Field("modbus_port")));
        assert_eq!(network_of(br#"{"ip":"10.0.0.1"}"#), Err(NetworkError::NotJson));
    }

    #[test]
    fn allow_list_bodies() {
        let list = allow_list_of(br#"{"networks":["192.0.2.0/24","10.1.2.3"]}"#).expect("a list");
        let nets: std::vec::Vec<Network> = list.iter().collect();
        assert_eq!(nets, [Network { ip: [192, 0, 2, 0], prefix: 24 }, Network { ip: [10, 1, 2, 3], prefix: 32 }]);
        assert_eq!(allow_list_of(br#"{"networks":[]}"#), Some(AllowList::EMPTY));
        let five = br#"{"networks":["1.0.0.0/8","2.0.0.0/8","3.0.0.0/8","4.0.0.0/8","5.0.0.0/8"]}"#;
        assert_eq!(allow_list_of(five), None);
        assert_eq!(allow_list_of(br#"{"networks":["192.0.2.0/40"]}"#), None);
        assert_eq!(allow_list_of(br#"{"networks":"192.0.2.0/24"}"#), None);
    }
}
