//! The web console's HTTP service on picoserve (docs/web.md): the JSON API under `/api/v1/`.
//! picoserve parses the request within its buffer and timeouts; this service routes it. Every
//! read and write of the module goes through the Modbus PDU engine ([`handle_pdu`]) with the
//! client's address, as a Modbus request would: the same checks, the same allow-list, the same
//! all-or-nothing commits, so the API and Modbus cannot disagree. Every state-changing request
//! needs a session and a signature ([`super::Sessions::verify`]).

use core::cell::RefCell;
use core::fmt::Write as _;

use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, RawMutex};
use embassy_sync::blocking_mutex::Mutex as Blocking;
use embassy_sync::mutex::Mutex;
use picoserve::io::Read;
use picoserve::request::{Path, Request};
use picoserve::response::{IntoResponse, Response, ResponseWriter, StatusCode};
use picoserve::routing::PathRouterService;
use picoserve::ResponseSent;
use remodaq_protocol::auth::{KEY_LEN, NONCE_LEN};
use remodaq_protocol::web::{hex, unhex, HEADER_COUNTER, HEADER_SESSION, HEADER_SIGNATURE, SESSION_ID_LEN};
use serde::Deserialize;

use super::{Login, LoginError, Refusal, Sessions, Signed, Verified};
use crate::discovery::Identity;
use crate::modbus::pdu::{handle_pdu, MAX_PDU};
use crate::modbus::RegisterMap;
use crate::module::{CommonSettings as _, SettingsAccess};

/// The sessions of the module's web console (one set for both connections).
pub type SharedSessions = Blocking<CriticalSectionRawMutex, RefCell<Sessions>>;

/// Largest JSON answer, bytes (125 registers as decimal numbers fit).
pub const MAX_ANSWER: usize = 1024;

/// The most registers or coils one GET reads: Modbus's limit for registers (125 of at most
/// "65535," fit [`MAX_ANSWER`]); 150 coils (150 "false," fit it, Modbus's 2000 would not).
const MAX_READ_REGISTERS: u16 = 125;
const MAX_READ_COILS: u16 = 150;

/// The API of one module to one client (`peer`: its IPv4 address, for the guessing budget, the
/// challenges and the Modbus allow-list). Built for each connection.
pub struct Api<'a, R: RawMutex, M> {
    /// The register map, as the Modbus server shares it.
    pub map: &'a Mutex<R, M>,
    /// The module's identity.
    pub identity: Identity,
    /// The web sessions.
    pub sessions: &'a SharedSessions,
    /// The client's address.
    pub peer: [u8; 4],
    /// The milliseconds since start, now.
    pub now_ms: fn() -> u64,
}

/// An answer: a status and a JSON text.
pub struct Answer {
    status: StatusCode,
    json: heapless::String<MAX_ANSWER>,
}

impl Answer {
    fn new(status: StatusCode) -> Self {
        Self { status, json: heapless::String::new() }
    }

    /// `{"error": what}` (and `"field": field` when one field is at fault).
    fn error(status: StatusCode, what: &str, field: Option<&str>) -> Self {
        let mut a = Self::new(status);
        let _ = write!(a.json, "{{\"error\":\"{what}\"");
        if let Some(field) = field {
            let _ = write!(a.json, ",\"field\":\"{field}\"");
        }
        let _ = a.json.push('}');
        a
    }

    fn no_content() -> Self {
        Self::new(StatusCode::NO_CONTENT)
    }
}

impl IntoResponse for Answer {
    async fn write_to<R: Read, W: ResponseWriter<Error = R::Error>>(
        self,
        connection: picoserve::response::Connection<'_, R>,
        response_writer: W,
    ) -> Result<ResponseSent, W::Error> {
        let response = Response::new(self.status, self.json.as_str())
            .with_content_type("application/json")
            .with_header("Cache-Control", "no-store");
        response_writer.write_response(connection, response).await
    }
}

#[derive(Deserialize)]
struct LoginBody<'a> {
    nonce: &'a str,
    page_nonce: &'a str,
    proof: &'a str,
}

#[derive(Deserialize)]
struct CoilBody {
    value: bool,
}

#[derive(Deserialize)]
struct RegisterBody {
    value: u16,
}

impl<R: RawMutex, M: RegisterMap + SettingsAccess> PathRouterService for Api<'_, R, M> {
    async fn call_path_router_service<Rd: Read, W: ResponseWriter<Error = Rd::Error>>(
        &self,
        _state: &(),
        _parameters: (),
        path: Path<'_>,
        mut request: Request<'_, Rd>,
        response_writer: W,
    ) -> Result<ResponseSent, W::Error> {
        let parts = request.parts;
        let method = parts.method();
        let target = path.encoded();
        let query = parts.query().map(|q| q.0);
        let full = full_target(target, query);
        let answer = match request.body_connection.body().read_all().await {
            Ok(body) => {
                let signed = Signed {
                    method,
                    target: full.as_str(),
                    body,
                    session: header(&parts, HEADER_SESSION).and_then(unhex::<SESSION_ID_LEN>),
                    counter: header(&parts, HEADER_COUNTER).and_then(|c| c.parse().ok()),
                    signature: header(&parts, HEADER_SIGNATURE).and_then(unhex::<KEY_LEN>),
                };
                let foreign =
                    header(&parts, "Origin").is_some_and(|origin| !same_origin(origin, header(&parts, "Host")));
                self.route(method, target, query, &signed, foreign).await
            }
            Err(_) => Answer::error(StatusCode::PAYLOAD_TOO_LARGE, "body too large", None),
        };
        answer.write_to(request.body_connection.finalize().await?, response_writer).await
    }
}

/// The value of header `name`, as text.
fn header<'a>(parts: &picoserve::request::RequestParts<'a>, name: &str) -> Option<&'a str> {
    parts.headers().get(name).and_then(|v| v.as_str().ok())
}

/// The request target as sent: the path, and `?` and the query when there is one.
fn full_target(path: &str, query: Option<&str>) -> heapless::String<256> {
    let mut t = heapless::String::new();
    let _ = t.push_str(path);
    if let Some(q) = query {
        let _ = t.push('?');
        let _ = t.push_str(q);
    }
    t
}

/// Whether `origin` (`http://host[:port]`) is the origin the request was sent to (`Host`).
fn same_origin(origin: &str, host: Option<&str>) -> bool {
    match (origin.strip_prefix("http://"), host) {
        (Some(rest), Some(host)) => rest.eq_ignore_ascii_case(host),
        _ => false,
    }
}

/// `?count=N` of a query (1 to `most`), 1 without one; `None` for anything else.
fn count(query: Option<&str>, most: u16) -> Option<u16> {
    let Some(query) = query else { return Some(1) };
    query.strip_prefix("count=").and_then(|n| n.parse().ok()).filter(|n| (1..=most).contains(n))
}

/// The status and text of a Modbus exception as an API error.
fn exception_answer(code: u8, field: &str) -> Answer {
    match code {
        2 => Answer::error(StatusCode::NOT_FOUND, "address not mapped for this access", Some("address")),
        3 => Answer::error(StatusCode::UNPROCESSABLE_ENTITY, "value refused", Some(field)),
        4 => Answer::error(StatusCode::INTERNAL_SERVER_ERROR, "the module could not apply it", None),
        // 01 (not a known function) and the access rules' refusal of a write.
        _ => Answer::error(StatusCode::FORBIDDEN, "refused by the module", None),
    }
}

impl<R: RawMutex, M: RegisterMap + SettingsAccess> Api<'_, R, M> {
    async fn route(
        &self,
        method: &str,
        target: &str,
        query: Option<&str>,
        signed: &Signed<'_>,
        foreign: bool,
    ) -> Answer {
        let mut segments = target.trim_start_matches('/').split('/');
        let (Some("api"), Some("v1")) = (segments.next(), segments.next()) else {
            return Answer::error(StatusCode::NOT_FOUND, "no such resource", None);
        };
        let resource = (segments.next(), segments.next(), segments.next());
        let state_changing = !(method.eq_ignore_ascii_case("GET") || method.eq_ignore_ascii_case("HEAD"));
        if state_changing && foreign {
            return Answer::error(StatusCode::FORBIDDEN, "request from another origin", None);
        }
        match (method, resource) {
            ("GET", (Some("identity"), None, None)) => self.identity(),
            ("POST", (Some("session"), Some("challenge"), None)) => self.challenge().await,
            ("POST", (Some("session"), None, None)) => self.login(signed.body).await,
            ("DELETE", (Some("session"), None, None)) => match self.verify(signed).await {
                Ok(_) => {
                    if let Some(id) = signed.session {
                        self.sessions.lock(|s| s.borrow_mut().end(&id));
                    }
                    Answer::no_content()
                }
                Err(why) => Answer::error(StatusCode::UNAUTHORIZED, why, None),
            },
            ("GET", (Some(table @ ("registers" | "coils")), Some(addr), None)) => {
                let Ok(addr) = addr.parse::<u16>() else {
                    return Answer::error(StatusCode::BAD_REQUEST, "not an address", Some("address"));
                };
                let registers = table == "registers";
                match count(query, if registers { MAX_READ_REGISTERS } else { MAX_READ_COILS }) {
                    Some(n) => self.read(registers, addr, n).await,
                    None => Answer::error(StatusCode::BAD_REQUEST, "count must be 1 to the limit", Some("count")),
                }
            }
            ("PUT", (Some(table @ ("registers" | "coils")), Some(addr), None)) => {
                let Ok(addr) = addr.parse::<u16>() else {
                    return Answer::error(StatusCode::BAD_REQUEST, "not an address", Some("address"));
                };
                if let Err(why) = self.verify(signed).await {
                    return Answer::error(StatusCode::UNAUTHORIZED, why, None);
                }
                self.write(table == "registers", addr, signed.body).await
            }
            (_, (Some("identity" | "session" | "registers" | "coils"), _, _)) => {
                Answer::error(StatusCode::METHOD_NOT_ALLOWED, "method not allowed here", None)
            }
            _ => Answer::error(StatusCode::NOT_FOUND, "no such resource", None),
        }
    }

    fn identity(&self) -> Answer {
        let id = &self.identity;
        let mut a = Answer::new(StatusCode::OK);
        let mut mac = [0u8; 12];
        let _ = write!(
            a.json,
            "{{\"model\":\"{:04X}\",\"name\":\"{}\",\"firmware\":\"{:04X}\",\"mac\":\"{}\"}}",
            id.model,
            id.name,
            id.version,
            hex(&id.mac, &mut mac).unwrap_or("")
        );
        a
    }

    async fn challenge(&self) -> Answer {
        let credential = self.map.lock().await.settings().password();
        let now = (self.now_ms)();
        let Some(c) = self.sessions.lock(|s| s.borrow_mut().challenge(&credential, self.peer, now)) else {
            return Answer::error(StatusCode::SERVICE_UNAVAILABLE, "the module is not ready for logins", None);
        };
        let (mut salt, mut nonce) = ([0u8; 32], [0u8; 2 * NONCE_LEN]);
        let mut a = Answer::new(StatusCode::OK);
        let _ = write!(
            a.json,
            "{{\"salt\":\"{}\",\"iterations\":{},\"nonce\":\"{}\"}}",
            hex(&c.salt, &mut salt).unwrap_or(""),
            c.iterations,
            hex(&c.nonce, &mut nonce).unwrap_or("")
        );
        a
    }

    async fn login(&self, body: &[u8]) -> Answer {
        let Ok((login, _)) = serde_json_core::from_slice::<LoginBody<'_>>(body) else {
            return Answer::error(StatusCode::BAD_REQUEST, "expected {nonce, page_nonce, proof}", None);
        };
        let (Some(module_nonce), Some(page_nonce), Some(proof)) =
            (unhex(login.nonce), unhex(login.page_nonce), unhex::<KEY_LEN>(login.proof))
        else {
            return Answer::error(StatusCode::BAD_REQUEST, "nonces are 32 hex digits, the proof 64", None);
        };
        let credential = self.map.lock().await.settings().password();
        let now = (self.now_ms)();
        let login = Login { module_nonce, page_nonce, proof };
        let mac = self.identity.mac;
        match self.sessions.lock(|s| s.borrow_mut().login(&credential, &mac, &login, self.peer, now)) {
            Ok(done) => {
                let (mut id, mut signature) = ([0u8; 2 * SESSION_ID_LEN], [0u8; 2 * KEY_LEN]);
                let mut a = Answer::new(StatusCode::OK);
                let _ = write!(
                    a.json,
                    "{{\"session\":\"{}\",\"signature\":\"{}\"}}",
                    hex(&done.session, &mut id).unwrap_or(""),
                    hex(&done.signature, &mut signature).unwrap_or("")
                );
                a
            }
            Err(LoginError::Challenge) => {
                Answer::error(StatusCode::UNAUTHORIZED, "challenge unknown, used or expired", Some("nonce"))
            }
            Err(LoginError::Wrong) => Answer::error(StatusCode::UNAUTHORIZED, "wrong password", None),
            Err(LoginError::Limited) => {
                Answer::error(StatusCode::TOO_MANY_REQUESTS, "too many wrong passwords: wait", None)
            }
        }
    }

    /// The signature check of a state-changing request, against the password in force; why
    /// it was refused.
    async fn verify(&self, signed: &Signed<'_>) -> Result<Verified, &'static str> {
        let credential = self.map.lock().await.settings().password();
        let now = (self.now_ms)();
        self.sessions.lock(|s| s.borrow_mut().verify(signed, &credential, now)).map_err(|refusal| match refusal {
            Refusal::Unsigned => "unsigned",
            Refusal::NoSession => "no session",
            Refusal::Stale => "stale counter",
            Refusal::BadSignature => "bad signature",
            Refusal::Malformed => "malformed method or target",
        })
    }

    async fn read(&self, registers: bool, addr: u16, n: u16) -> Answer {
        let function = if registers { 0x03 } else { 0x01 };
        let [a_hi, a_lo] = addr.to_be_bytes();
        let [n_hi, n_lo] = n.to_be_bytes();
        let mut resp = [0u8; MAX_PDU];
        let len = handle_pdu(self.map, self.peer, &[function, a_hi, a_lo, n_hi, n_lo], &mut resp).await;
        let Some(data) = resp.get(2..len).filter(|_| resp[0] == function) else {
            return exception_answer(resp[1], "address");
        };
        let mut a = Answer::new(StatusCode::OK);
        let _ = a.json.push_str("{\"values\":[");
        for i in 0..usize::from(n) {
            let sep = if i == 0 { "" } else { "," };
            let _ = if registers {
                let v = data.get(2 * i..2 * i + 2).map_or(0, |w| u16::from_be_bytes([w[0], w[1]]));
                write!(a.json, "{sep}{v}")
            } else {
                let on = data.get(i / 8).is_some_and(|b| b >> (i % 8) & 1 == 1);
                write!(a.json, "{sep}{on}")
            };
        }
        let _ = a.json.push_str("]}");
        a
    }

    async fn write(&self, registers: bool, addr: u16, body: &[u8]) -> Answer {
        let (function, value) = if registers {
            match serde_json_core::from_slice::<RegisterBody>(body) {
                Ok((b, _)) => (0x06, b.value),
                Err(_) => return Answer::error(StatusCode::BAD_REQUEST, "expected {value: 0..65535}", Some("value")),
            }
        } else {
            match serde_json_core::from_slice::<CoilBody>(body) {
                Ok((b, _)) => (0x05, if b.value { 0xFF00 } else { 0 }),
                Err(_) => return Answer::error(StatusCode::BAD_REQUEST, "expected {value: true|false}", Some("value")),
            }
        };
        let [a_hi, a_lo] = addr.to_be_bytes();
        let [v_hi, v_lo] = value.to_be_bytes();
        let mut resp = [0u8; MAX_PDU];
        let len = handle_pdu(self.map, self.peer, &[function, a_hi, a_lo, v_hi, v_lo], &mut resp).await;
        if len >= 5 && resp[0] == function {
            Answer::no_content()
        } else {
            exception_answer(resp[1], "value")
        }
    }
}
