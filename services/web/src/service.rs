//! The web console's HTTP service on picoserve (docs/web.md): the JSON API under `/api/v1/`.
//! picoserve parses the request within its buffer and timeouts; this service routes it. Every
//! read and write of the module goes through the Modbus PDU engine ([`handle_pdu`]) with the
//! client's address, as a Modbus request would: the same checks, the same allow-list, the same
//! all-or-nothing commits, so the API and Modbus cannot disagree. Every state-changing request
//! needs a session and a signature ([`super::Sessions::verify`]).

use core::cell::{Cell, RefCell};
use core::fmt::Write as _;

use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, RawMutex};
use embassy_sync::blocking_mutex::Mutex as Blocking;
use embassy_sync::mutex::Mutex;
use picoserve::io::{Read, Socket};
use picoserve::request::{Path, Request};
use picoserve::response::{IntoResponse, Response, ResponseWriter, StatusCode};
use picoserve::routing::PathRouterService;
use picoserve::{Config, EmbassyRuntime, ResponseSent, Router, Timeouts};
use remodaq_protocol::auth::{KEY_LEN, NONCE_LEN};
use remodaq_protocol::m8318::{InputType, REG_INPUT_TYPE};
use remodaq_protocol::m8350::{DiMode, REG_DI_MODE};
use remodaq_protocol::resources::{self, Field, Format, Resource};
use remodaq_protocol::web::{hex, unhex, HEADER_COUNTER, HEADER_SESSION, HEADER_SIGNATURE, SESSION_ID_LEN};
use remodaq_protocol::{u32_low_first, words_low_first, Table};

use crate::json::Object;
use crate::sessions::{Login, LoginError, Refusal, Sessions, Signed, Verified};
use remodaq_shared::identity::Identity;
use remodaq_shared::modbus::pdu::{handle_pdu, MAX_PDU};
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::{CommonSettings as _, SettingsAccess, Store};
use remodaq_shared::password::Credential;
use embedded_storage_async::nor_flash::NorFlash;

/// The sessions of the module's web console (one set for both connections).
pub type SharedSessions = Blocking<CriticalSectionRawMutex, RefCell<Sessions>>;

/// The module's web sessions.
pub static SESSIONS: SharedSessions = Blocking::new(RefCell::new(Sessions::new()));

/// HTTP connections served at once (issue #25: at most 2, each in a task of its own, never a
/// Modbus slot).
pub const CONNECTIONS: usize = remodaq_shared::sockets::WEB_CONNECTIONS;

/// The request head and body together must fit (a larger head: 431 and closed; a larger
/// body: 413). A login is about 300 bytes of head and 150 of body.
pub const HTTP_BUFFER: usize = 1536;

/// The timeouts of every connection: the first byte within 5 s, the whole request within 3 s
/// of it, each write within 1 s; one request per connection (no keep-alive: a connection
/// slot is not held between a page's requests).
pub static CONFIG: Config = Config::new(Timeouts {
    start_read_request: embassy_time::Duration::from_secs(5),
    persistent_start_read_request: embassy_time::Duration::from_secs(1),
    read_request: embassy_time::Duration::from_secs(3),
    write: embassy_time::Duration::from_secs(1),
})
.close_connection_after_response();

/// Milliseconds since the module started.
fn now_ms() -> u64 {
    embassy_time::Instant::now().as_millis()
}

/// picoserve's [`picoserve::io::Write::write_with`] for a writer that has no buffer of its own
/// to lend (a std socket, a test's output): `f` formats into a 1 KiB buffer, which is then
/// written whole.
pub async fn write_with_buffer<W: embedded_io_async::Write, F: FnOnce(picoserve::mem::BorrowedCursor<'_>) -> T, T>(
    writer: &mut W,
    f: F,
) -> Result<T, W::Error> {
    let mut buffer = [0u8; 1024];
    let mut buffer = picoserve::mem::BorrowedBuffer::new(&mut buffer);
    let output = f(buffer.unfilled());
    writer.write_all(buffer.filled()).await.map(|()| output)
}

/// How a connection ended.
pub struct Served<E: embedded_io_async::Error> {
    /// A signed restart request of this connection was answered: restart now (the connection
    /// is closed; the other connection's requests never set this).
    pub restart: bool,
    /// The connection's end: an error or a timeout of picoserve's.
    pub result: Result<(), picoserve::Error<E>>,
}

/// Serves one connection (`socket`, from the client at `peer`) with the module's API, in
/// `buffer`; every board's connection task calls this.
pub async fn serve_connection<R: RawMutex, M: RegisterMap + SettingsAccess, F: NorFlash, S: Socket<EmbassyRuntime>>(
    map: &Mutex<R, M>,
    store: &Store<F, M::Settings>,
    identity: Identity,
    peer: [u8; 4],
    socket: S,
    buffer: &mut [u8; HTTP_BUFFER],
) -> Served<S::Error> {
    let restart = Cell::new(false);
    let api = Api { map, store, identity, sessions: &SESSIONS, peer, now_ms, restart: &restart };
    let app = Router::from_service(api);
    let serve = picoserve::Server::custom(&app, picoserve::time::EmbassyTimer, &CONFIG, buffer).serve(socket);
    // picoserve's timeouts bound each read and write, not a client that reads its answer a byte
    // at a time: the whole connection is bounded too (dropping it closes the socket).
    let result = match embassy_time::with_timeout(CONNECTION_MAX, serve).await {
        Ok(served) => served.map(|_| ()),
        Err(_) => Ok(()),
    };
    Served { restart: restart.get(), result }
}

/// The longest a connection is served: one request (5 s to start, 3 s to arrive), its answer,
/// and the close.
pub const CONNECTION_MAX: embassy_time::Duration = embassy_time::Duration::from_secs(10);

/// The console's pages: path, type, and the file gzip-compressed at build time (build.rs).
const PAGES: [(&str, &str, &[u8]); 4] = [
    ("/", "text/html; charset=utf-8", include_bytes!(concat!(env!("OUT_DIR"), "/index.html.gz"))),
    ("/app.js", "text/javascript; charset=utf-8", include_bytes!(concat!(env!("OUT_DIR"), "/app.js.gz"))),
    ("/auth.js", "text/javascript; charset=utf-8", include_bytes!(concat!(env!("OUT_DIR"), "/auth.js.gz"))),
    ("/style.css", "text/css; charset=utf-8", include_bytes!(concat!(env!("OUT_DIR"), "/style.css.gz"))),
];

/// The headers of a JSON answer, and what every answer says about itself: a page's scripts
/// come from the module only and no other site may frame it (clickjacking); browsers take the
/// declared types as they are.
const JSON_HEADERS: [(&str, &str); 4] = [
    ("Cache-Control", "no-store"),
    ("Content-Security-Policy", "default-src 'self'; frame-ancestors 'none'; form-action 'self'"),
    ("X-Content-Type-Options", "nosniff"),
    ("Referrer-Policy", "no-referrer"),
];

/// The headers of a page's file: compressed at build time (every browser takes gzip), checked
/// again at each load, and what every answer says about itself.
const PAGE_HEADERS: [(&str, &str); 5] =
    [("Content-Encoding", "gzip"), ("Cache-Control", "no-cache"), JSON_HEADERS[1], JSON_HEADERS[2], JSON_HEADERS[3]];

/// Largest JSON answer, bytes (the 8350's 12 DIs with every field fit, about 1.3 KB).
pub const MAX_ANSWER: usize = 2048;

/// The most values one resource read copies under the map's lock (the 8350's 12 DIs of 7
/// shown fields).
const MAX_VALUES: usize = 96;

/// The most registers or coils one GET reads: Modbus's limit for registers (125 of at most
/// "65535," fit [`MAX_ANSWER`]); 150 coils (150 "false," fit it, Modbus's 2000 would not).
const MAX_READ_REGISTERS: u16 = 125;
const MAX_READ_COILS: u16 = 150;

/// The API of one module to one client (`peer`: its IPv4 address, for the guessing budget, the
/// challenges and the Modbus allow-list). Built for each connection.
pub struct Api<'a, R: RawMutex, M: SettingsAccess, F: NorFlash> {
    /// The register map, as the Modbus server shares it.
    pub map: &'a Mutex<R, M>,
    /// The settings store, as discovery shares it.
    pub store: &'a Store<F, M::Settings>,
    /// The module's identity.
    pub identity: Identity,
    /// The web sessions.
    pub sessions: &'a SharedSessions,
    /// The client's address.
    pub peer: [u8; 4],
    /// The milliseconds since start, now.
    pub now_ms: fn() -> u64,
    /// Set by a signed restart request: the connection's task restarts the module once its
    /// answer is sent.
    pub restart: &'a Cell<bool>,
}

/// A JSON text being written: once a piece did not fit, it is marked cut (and answered as an
/// error, never sent cut short).
#[derive(Default)]
pub struct Json {
    text: heapless::String<MAX_ANSWER>,
    cut: bool,
}

impl core::fmt::Write for Json {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        if self.cut || self.text.push_str(s).is_err() {
            self.cut = true;
            return Err(core::fmt::Error);
        }
        Ok(())
    }
}

impl Json {
    pub(super) fn push(&mut self, c: char) {
        let _ = self.write_char(c);
    }

    pub(super) fn push_str(&mut self, s: &str) {
        let _ = self.write_str(s);
    }
}

/// An answer: a status and a JSON text.
pub struct Answer {
    pub(super) status: StatusCode,
    pub(super) json: Json,
    /// A page's file instead of the JSON: its type and its gzip-compressed bytes.
    page: Option<(&'static str, &'static [u8])>,
}

impl Answer {
    pub(super) fn new(status: StatusCode) -> Self {
        Self { status, json: Json::default(), page: None }
    }

    /// `{"error": what}` (and `"field": field` when one field is at fault).
    pub(super) fn error(status: StatusCode, what: &str, field: Option<&str>) -> Self {
        let mut a = Self::new(status);
        let _ = write!(a.json, "{{\"error\":\"{what}\"");
        if let Some(field) = field {
            let _ = write!(a.json, ",\"field\":\"{field}\"");
        }
        a.json.push('}');
        a
    }

    pub(super) fn no_content() -> Self {
        Self::new(StatusCode::NO_CONTENT)
    }

    /// 202: done once the answer is sent (a restart).
    pub(super) fn accepted() -> Self {
        let mut a = Self::new(StatusCode::ACCEPTED);
        a.json.push_str("{\"restarting\":true}");
        a
    }
}

impl IntoResponse for Answer {
    async fn write_to<R: Read, W: ResponseWriter<Error = R::Error>>(
        self,
        connection: picoserve::response::Connection<'_, R>,
        response_writer: W,
    ) -> Result<ResponseSent, W::Error> {
        // One kind of response for every answer: one copy of picoserve's writer in flash.
        let (status, kind, body, headers): (_, _, &[u8], &[(&str, &str)]) = match self.page {
            Some((kind, gz)) => (self.status, kind, gz, &PAGE_HEADERS),
            None if self.json.cut => (
                StatusCode::INTERNAL_SERVER_ERROR,
                "application/json",
                b"{\"error\":\"answer too long\"}",
                &JSON_HEADERS,
            ),
            None => (self.status, "application/json", self.json.text.as_bytes(), &JSON_HEADERS),
        };
        let response = Response::new(status, body).with_content_type(kind).with_headers(headers);
        response_writer.write_response(connection, response).await
    }
}

/// What a field reads as.
#[derive(Clone, Copy)]
enum Seen {
    /// The module does not map it (left out of the answer).
    Unmapped,
    /// `null` (a DI's frequency outside frequency mode).
    Null,
    /// Its value (two registers: low word first).
    Value(u32),
}

impl<R: RawMutex, M: RegisterMap + SettingsAccess, F: NorFlash> PathRouterService for Api<'_, R, M, F> {
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
        let answer = if !host_is_an_address(header(&parts, "Host")) {
            // DNS rebinding: a hostile page whose name the attacker's DNS turns into the module's
            // address sends its requests with its own name as the Host (docs/web.md).
            Answer::error(StatusCode::MISDIRECTED_REQUEST, "reach the module by its address", None)
        } else if let Some((_, kind, gz)) = PAGES.iter().find(|(p, ..)| *p == target).filter(|_| method == "GET") {
            Answer { page: Some((kind, gz)), ..Answer::new(StatusCode::OK) }
        } else {
            let query = parts.query().map(|q| q.0);
            let full = full_target(target, query);
            match (request.body_connection.body().read_all().await, full.as_ref()) {
                (Ok(_), None) => Answer::error(StatusCode::URI_TOO_LONG, "target too long", None),
                (Ok(body), Some(full)) => {
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
                    // The password in force, read once for the request's checks.
                    let credential = self.map.lock().await.settings().password();
                    self.route(method, target, query, &signed, foreign, &credential).await
                }
                (Err(_), _) => Answer::error(StatusCode::PAYLOAD_TOO_LARGE, "body too large", None),
            }
        };
        answer.write_to(request.body_connection.finalize().await?, response_writer).await
    }
}

/// The value of header `name`, as text.
fn header<'a>(parts: &picoserve::request::RequestParts<'a>, name: &str) -> Option<&'a str> {
    parts.headers().get(name).and_then(|v| v.as_str().ok())
}

/// The request target as sent: the path, and `?` and the query when there is one; `None` when
/// it is longer than any resource's (it could not be signed whole).
fn full_target(path: &str, query: Option<&str>) -> Option<heapless::String<256>> {
    let mut t = heapless::String::new();
    t.push_str(path).ok()?;
    if let Some(q) = query {
        t.push('?').ok()?;
        t.push_str(q).ok()?;
    }
    Some(t)
}

/// Whether `host` (a request's `Host`) names the module by an address: an IPv4 address in
/// dotted decimal, an IPv6 address in brackets (the simulator on `[::1]`) or `localhost`, with a
/// port or without. A page served under a DNS name could be the attacker's, its name rebound to
/// the module's address; the console is reached by the address the utility's search shows
/// (docs/web.md, "Decisions").
fn host_is_an_address(host: Option<&str>) -> bool {
    let Some(host) = host else { return false };
    let port_is_right = |port: &str| port.bytes().all(|b| b.is_ascii_digit()) && port.parse::<u16>().is_ok();
    if let Some(rest) = host.strip_prefix('[') {
        let Some((address, after)) = rest.split_once(']') else { return false };
        let port_ok = after.is_empty() || after.strip_prefix(':').is_some_and(port_is_right);
        // Only an IPv6 literal can stand between brackets in a URL (RFC 3986, section 3.2.2);
        // its characters are checked, not its groups (core's IPv6 reader takes about 1 KB).
        let literal = address.contains(':') && address.bytes().all(|b| b.is_ascii_hexdigit() || b == b':' || b == b'.');
        return port_ok && literal;
    }
    let name = match host.rsplit_once(':') {
        Some((name, port)) if port_is_right(port) => name,
        Some(_) => return false,
        None => host,
    };
    name.eq_ignore_ascii_case("localhost") || remodaq_protocol::net::parse_ipv4(name).is_some()
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

impl<R: RawMutex, M: RegisterMap + SettingsAccess, F: NorFlash> Api<'_, R, M, F> {
    async fn route(
        &self,
        method: &str,
        target: &str,
        query: Option<&str>,
        signed: &Signed<'_>,
        foreign: bool,
        credential: &Credential,
    ) -> Answer {
        let mut segments = target.trim_start_matches('/').split('/');
        let (Some("api"), Some("v1")) = (segments.next(), segments.next()) else {
            return Answer::error(StatusCode::NOT_FOUND, "no such resource", None);
        };
        let resource = (segments.next(), segments.next(), segments.next());
        if segments.next().is_some() {
            return Answer::error(StatusCode::NOT_FOUND, "no such resource", None);
        }
        let state_changing = !(method.eq_ignore_ascii_case("GET") || method.eq_ignore_ascii_case("HEAD"));
        if state_changing && foreign {
            return Answer::error(StatusCode::FORBIDDEN, "request from another origin", None);
        }
        match (method, resource) {
            ("GET", (Some("identity"), None, None)) => self.identity(),
            ("POST", (Some("session"), Some("challenge"), None)) => self.challenge(credential),
            ("POST", (Some("session"), None, None)) => self.login(signed.body, credential),
            ("DELETE", (Some("session"), None, None)) => match self.verify(signed, credential) {
                Ok(_) => {
                    if let Some(id) = signed.session {
                        self.sessions.lock(|s| s.borrow_mut().end(&id));
                        crate::firmware::release(&id);
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
                if let Err(why) = self.verify(signed, credential) {
                    return Answer::error(StatusCode::UNAUTHORIZED, why, None);
                }
                self.write(table == "registers", addr, signed.body).await
            }
            ("GET", (Some("network"), None, None)) => self.network().await,
            ("GET", (Some("firmware"), None, None)) => self.firmware(),
            ("POST", (Some("firmware"), None | Some("finish"), None)) | ("PUT", (Some("firmware"), Some(_), None)) => {
                let verified = match self.verify(signed, credential) {
                    Ok(verified) => verified,
                    Err(why) => return Answer::error(StatusCode::UNAUTHORIZED, why, None),
                };
                // As the update service: not with the factory password (docs/update.md).
                if verified.factory {
                    return Answer::error(StatusCode::FORBIDDEN, "set a password first", None);
                }
                let session = signed.session.unwrap_or_default();
                match (method, resource.1) {
                    ("POST", None) => self.firmware_begin(session, signed.body).await,
                    ("POST", Some(_)) => self.firmware_finish(session).await,
                    (_, Some(offset)) => self.firmware_write(session, offset, signed.body).await,
                    _ => Answer::error(StatusCode::METHOD_NOT_ALLOWED, "method not allowed here", None),
                }
            }
            (method @ ("PUT" | "GET"), (Some(name @ ("network" | "access" | "password")), None, None))
            | (method @ "POST", (Some(name @ ("restart" | "password")), None | Some("key"), None)) => {
                // Reading the allow-list needs a session too (discovery shows it only with the
                // password); every other read here is open.
                let verified = match self.verify(signed, credential) {
                    Ok(verified) => verified,
                    Err(why) => return Answer::error(StatusCode::UNAUTHORIZED, why, None),
                };
                match (method, name, resource.1) {
                    ("PUT", "network", _) => self.set_network(signed.body).await,
                    ("GET", "access", _) => self.access().await,
                    // As discovery: the factory password, which anyone knows, does not restrict
                    // who may write (docs/security.md).
                    ("PUT", "access", _) if verified.factory => {
                        Answer::error(StatusCode::FORBIDDEN, "set a password first", None)
                    }
                    ("PUT", "access", _) => self.set_access(signed.body).await,
                    // A verified request names its session.
                    ("POST", "password", Some(_)) => self.password_key(signed.session.unwrap_or_default()),
                    ("PUT", "password", _) => self.set_password(signed.session.unwrap_or_default(), signed.body).await,
                    ("POST", "restart", None) => self.restart(),
                    _ => Answer::error(StatusCode::METHOD_NOT_ALLOWED, "method not allowed here", None),
                }
            }
            (
                _,
                (
                    Some(
                        "identity" | "session" | "registers" | "coils" | "network" | "access" | "restart" | "password"
                        | "firmware",
                    ),
                    _,
                    _,
                ),
            ) => Answer::error(StatusCode::METHOD_NOT_ALLOWED, "method not allowed here", None),
            (_, (Some(name), a, b)) => {
                let Some(r) = resources::of(self.identity.model).iter().find(|r| r.name == name) else {
                    return Answer::error(StatusCode::NOT_FOUND, "no such resource", None);
                };
                // A list's item: `/{n}`; a field to write: the last segment.
                let (item, field) = if r.count > 0 { (a, b) } else { (None, a.or(b).filter(|_| b.is_none())) };
                let n = match item.map(|n| n.parse::<u16>().ok().filter(|n| *n < r.count)) {
                    Some(None) => return Answer::error(StatusCode::NOT_FOUND, "no such item", Some("item")),
                    Some(Some(n)) => Some(n),
                    None => None,
                };
                match (method, field) {
                    ("GET", None) => self.show(r, n).await,
                    ("PUT", Some(field)) => {
                        let Some(f) = r.field(field) else {
                            return Answer::error(StatusCode::NOT_FOUND, "no such field", Some("field"));
                        };
                        if r.count > 0 && n.is_none() {
                            return Answer::error(StatusCode::NOT_FOUND, "no such item", Some("item"));
                        }
                        if let Err(why) = self.verify(signed, credential) {
                            return Answer::error(StatusCode::UNAUTHORIZED, why, None);
                        }
                        self.change(f, n.unwrap_or(0), signed.body).await
                    }
                    _ => Answer::error(StatusCode::METHOD_NOT_ALLOWED, "method not allowed here", None),
                }
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

    fn challenge(&self, credential: &Credential) -> Answer {
        let now = (self.now_ms)();
        let Some(c) = self.sessions.lock(|s| s.borrow_mut().challenge(credential, self.peer, now)) else {
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

    fn login(&self, body: &[u8], credential: &Credential) -> Answer {
        let fields = Object::parse(body).and_then(|o| Some((o.str("nonce")?, o.str("page_nonce")?, o.str("proof")?)));
        let Some((nonce, page_nonce, proof)) = fields else {
            return Answer::error(StatusCode::BAD_REQUEST, "expected {nonce, page_nonce, proof}", None);
        };
        let (Some(module_nonce), Some(page_nonce), Some(proof)) =
            (unhex(nonce), unhex(page_nonce), unhex::<KEY_LEN>(proof))
        else {
            return Answer::error(StatusCode::BAD_REQUEST, "nonces are 32 hex digits, the proof 64", None);
        };
        let now = (self.now_ms)();
        let login = Login { module_nonce, page_nonce, proof };
        let mac = self.identity.mac;
        match self.sessions.lock(|s| s.borrow_mut().login(credential, &mac, &login, self.peer, now)) {
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
    fn verify(&self, signed: &Signed<'_>, credential: &Credential) -> Result<Verified, &'static str> {
        let now = (self.now_ms)();
        self.sessions.lock(|s| s.borrow_mut().verify(signed, credential, now)).map_err(|refusal| match refusal {
            Refusal::Unsigned => "unsigned",
            Refusal::NoSession => "no session",
            Refusal::Stale => "stale counter",
            Refusal::BadSignature => "bad signature",
            Refusal::Malformed => "malformed method or target",
        })
    }

    /// A run of registers or coils as they stand (no flag cleared: [`RegisterMap::observe`]),
    /// read under one lock of the map. Reads are never refused by the allow-list and, unlike a
    /// Modbus read, do not feed the host watchdog (docs/web.md).
    async fn read(&self, registers: bool, addr: u16, n: u16) -> Answer {
        let table = if registers { Table::Registers } else { Table::Bits };
        let mut values = [0u16; MAX_READ_COILS as usize];
        let values = &mut values[..usize::from(n)];
        {
            let mut map = self.map.lock().await;
            if !readable(&*map, table, addr, n) {
                return exception_answer(2, "address");
            }
            // addr + i stays within 16 bits: checked above.
            for (i, v) in (0..n).zip(values.iter_mut()) {
                *v = map.observe(table, addr + i);
            }
        }
        let mut a = Answer::new(StatusCode::OK);
        a.json.push_str("{\"values\":[");
        for (i, v) in values.iter().enumerate() {
            let sep = if i == 0 { "" } else { "," };
            let _ = if registers { write!(a.json, "{sep}{v}") } else { write!(a.json, "{sep}{}", *v != 0) };
        }
        a.json.push_str("]}");
        a
    }

    /// A write of registers or coils at `addr` from a body `{"value": ...}`.
    async fn write(&self, registers: bool, addr: u16, body: &[u8]) -> Answer {
        let request = if registers {
            match Object::parse(body).and_then(|o| o.u16("value")) {
                Some(v) => Pdu::word(addr, v),
                None => return Answer::error(StatusCode::BAD_REQUEST, "expected {value: 0..65535}", Some("value")),
            }
        } else {
            match Object::parse(body).and_then(|o| o.bool("value")) {
                Some(v) => Pdu::bit(addr, v),
                None => return Answer::error(StatusCode::BAD_REQUEST, "expected {value: true|false}", Some("value")),
            }
        };
        self.apply(&request, "value").await
    }

    /// Carries out a write request through the Modbus PDU engine, with this client's address:
    /// the map's admission (the allow-list), checks and commit, as a Modbus write.
    async fn apply(&self, request: &Pdu, field: &str) -> Answer {
        let mut resp = [0u8; MAX_PDU];
        let len = handle_pdu(self.map, self.peer, request.bytes(), &mut resp).await;
        if len >= 5 && resp[0] == request.bytes()[0] {
            Answer::no_content()
        } else {
            exception_answer(resp[1], field)
        }
    }

    /// `GET /api/v1/{resource}` (every item) or `/api/v1/{resource}/{n}` (one).
    async fn show(&self, r: &Resource, item: Option<u16>) -> Answer {
        let items = match item {
            Some(n) => n..n + 1,
            None => 0..r.count.max(1),
        };
        let shown = || r.fields.iter().filter(|f| f.shown);
        let mut values: heapless::Vec<Seen, MAX_VALUES> = heapless::Vec::new();
        let input_type = {
            let mut map = self.map.lock().await;
            for n in items.clone() {
                for f in shown() {
                    let _ = values.push(seen(&mut *map, f, n));
                }
            }
            let engineering = r.fields.iter().any(|f| f.format == Format::Engineering);
            engineering.then(|| InputType::from_code(map.observe(Table::Registers, REG_INPUT_TYPE) as u8)).flatten()
        };
        let mut a = Answer::new(StatusCode::OK);
        let list = item.is_none() && r.count > 0;
        if list {
            let _ = write!(a.json, "{{\"{}\":[", r.name);
        }
        let mut values = values.iter();
        for n in items {
            // The executor is shared with Modbus: formatting a long list gives way between
            // items, so that a Modbus answer waits for one item at most (docs/web.md).
            embassy_futures::yield_now().await;
            if n > 0 && list {
                a.json.push(',');
            }
            a.json.push('{');
            let mut first = true;
            for (f, v) in shown().zip(&mut values) {
                let Seen::Value(v) = *v else {
                    if matches!(v, Seen::Null) {
                        let _ = write!(a.json, "{}\"{}\":null", if first { "" } else { "," }, f.name);
                        first = false;
                    }
                    continue;
                };
                let _ = write!(a.json, "{}\"{}\":", if first { "" } else { "," }, f.name);
                first = false;
                json_value(&mut a.json, f, v, input_type.as_ref());
            }
            a.json.push('}');
        }
        if list {
            a.json.push_str("]}");
        }
        a
    }

    /// `PUT /api/v1/{resource}[/{n}]/{field}` with `{"value": ...}`: one Modbus write.
    async fn change(&self, f: &Field, n: u16, body: &[u8]) -> Answer {
        match write_request(f, n, body) {
            Ok(request) => self.apply(&request, f.name).await,
            Err(WriteError::ReadOnly) => {
                Answer::error(StatusCode::METHOD_NOT_ALLOWED, "the field is read-only", Some(f.name))
            }
            Err(WriteError::NotAValue) => {
                Answer::error(StatusCode::UNPROCESSABLE_ENTITY, "not a value of this field", Some(f.name))
            }
        }
    }
}

/// Why a body is no write of a field.
#[derive(Debug, PartialEq, Eq)]
pub enum WriteError {
    /// The API does not write this field.
    ReadOnly,
    /// The body is not `{"value": ...}` with a value of the field's format.
    NotAValue,
}

/// The Modbus write request of a body `{"value": ...}` for field `f` of item `n`: code 05 for
/// a bit, 06 for a register, 16 for a 32-bit value; the register map still checks the value.
pub fn write_request(f: &Field, n: u16, body: &[u8]) -> Result<Pdu, WriteError> {
    if !f.writable {
        return Err(WriteError::ReadOnly);
    }
    let addr = f.addr(n);
    let value = Object::parse(body);
    let request = match f.format {
        Format::Bool => value.and_then(|o| o.bool("value")).map(|v| Pdu::bit(addr, v)),
        Format::Word | Format::InputType => value.and_then(|o| o.u16("value")).map(|v| Pdu::word(addr, v)),
        Format::Long => value.and_then(|o| o.u32("value")).map(|v| Pdu::long(addr, v)),
        // A decimal number of °C with at most two decimals (no float parsing in the image);
        // the map checks the range.
        Format::Hundredths => value
            .and_then(|o| o.number("value"))
            .and_then(hundredths)
            .and_then(|h| i16::try_from(h).ok())
            .map(|h| Pdu::word(addr, h as u16)),
        Format::Named(names) => value
            .and_then(|o| o.str("value"))
            .and_then(|v| names.iter().position(|name| *name == v))
            .map(|i| Pdu::word(addr, i as u16)),
        Format::MaskBit | Format::Engineering | Format::Frequency | Format::Ipv4 => return Err(WriteError::ReadOnly),
    };
    request.ok_or(WriteError::NotAValue)
}

/// A JSON number (`number`, as [`Object::number`] gives it) of at most two decimals (`-2`,
/// `1.25`), in hundredths.
fn hundredths(number: &str) -> Option<i32> {
    let (negative, digits) = match number.strip_prefix('-') {
        Some(digits) => (true, digits),
        None => (false, number),
    };
    let (whole, fraction) = match digits.split_once('.') {
        Some((whole, fraction)) if !fraction.is_empty() => (whole, fraction),
        Some(_) => return None,
        None => (digits, ""),
    };
    let decimal = |t: &str| !t.is_empty() && t.len() <= 5 && t.bytes().all(|b| b.is_ascii_digit());
    if !decimal(whole) || !(fraction.is_empty() || decimal(fraction)) || fraction.len() > 2 {
        return None;
    }
    let cents = match fraction.len() {
        0 => 0,
        1 => fraction.parse::<i32>().ok()? * 10,
        _ => fraction.parse::<i32>().ok()?,
    };
    let h = whole.parse::<i32>().ok()? * 100 + cents;
    Some(if negative { -h } else { h })
}

/// Writes `thousandths` as a decimal number with three decimals.
fn write_thousandths(json: &mut Json, thousandths: i64) -> core::fmt::Result {
    let sign = if thousandths < 0 { "-" } else { "" };
    let a = thousandths.unsigned_abs();
    write!(json, "{sign}{}.{:03}", a / 1000, a % 1000)
}

/// Whether `n` addresses from `addr` lie inside the 16-bit space and the map lets them be read.
fn readable<M: RegisterMap>(map: &M, table: Table, addr: u16, n: u16) -> bool {
    u32::from(addr) + u32::from(n) <= 0x1_0000 && map.allows(table, addr, n, false)
}

/// What field `f` of item `n` reads as, from the map as it stands.
fn seen<M: RegisterMap>(map: &mut M, f: &Field, n: u16) -> Seen {
    let addr = f.addr(n);
    if !readable(map, f.table, addr, f.words()) {
        return Seen::Unmapped;
    }
    if matches!(f.format, Format::Long | Format::Ipv4) && f.table == Table::Registers {
        let mut words = [0u16; 2];
        map.observe_registers(addr, &mut words);
        return Seen::Value(u32_low_first(words[0], words[1]));
    }
    let low = map.observe(f.table, addr);
    Seen::Value(match f.format {
        Format::MaskBit => u32::from(low >> (n % 16) & 1),
        Format::Frequency => {
            if map.observe(Table::Registers, REG_DI_MODE + n) != DiMode::Frequency as u16 {
                return Seen::Null;
            }
            u32::from(low)
        }
        _ => u32::from(low),
    })
}

/// Writes the JSON value of field `f` read as `v` (`input_type`: the 8318's, for its values).
fn json_value(json: &mut Json, f: &Field, v: u32, input_type: Option<&InputType>) {
    let _ = match f.format {
        Format::Bool | Format::MaskBit => write!(json, "{}", v != 0),
        Format::Word | Format::Long | Format::Frequency => write!(json, "{v}"),
        Format::Hundredths => {
            let h = i32::from(v as u16 as i16);
            let sign = if h < 0 { "-" } else { "" };
            write!(json, "{sign}{}.{:02}", h.unsigned_abs() / 100, h.unsigned_abs() % 100)
        }
        Format::Named(names) => match names.get(v as usize) {
            Some(name) => write!(json, "\"{name}\""),
            None => write!(json, "{v}"),
        },
        // spec §2.3 inverted in integers (every range's ends are whole units): lo + raw / 65535
        // x (hi - lo), in thousandths, rounded (no float formatting in the image).
        Format::Engineering => match input_type {
            Some(t) => {
                let (lo, hi) = (t.lo as i64, t.hi as i64);
                write_thousandths(json, lo * 1000 + (i64::from(v as u16) * (hi - lo) * 1000 + 32767) / 65535)
            }
            None => write!(json, "null"),
        },
        Format::InputType => match InputType::from_code(v as u8).filter(|_| v <= 0xFF) {
            Some(t) => {
                let thermocouple = t.thermocouple().map_or("", |tc| tc.letter());
                write!(
                    json,
                    "{{\"code\":{v},\"unit\":\"{}\",\"lo\":{},\"hi\":{},\"thermocouple\":\"{thermocouple}\"}}",
                    resources::unit(&t),
                    t.lo as i64,
                    t.hi as i64
                )
            }
            None => write!(json, "{{\"code\":{v}}}"),
        },
        Format::Ipv4 => {
            let [c, d, a, b] = v.to_be_bytes();
            write!(json, "\"{a}.{b}.{c}.{d}\"")
        }
    };
}

/// A Modbus write request PDU (at most code 16 with two registers).
pub struct Pdu {
    bytes: [u8; 10],
    len: usize,
}

impl Pdu {
    /// The request's bytes, from the function code.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes[..self.len]
    }

    /// Code 05: one coil.
    fn bit(addr: u16, on: bool) -> Self {
        let [a, b] = addr.to_be_bytes();
        Self { bytes: [0x05, a, b, if on { 0xFF } else { 0 }, 0, 0, 0, 0, 0, 0], len: 5 }
    }

    /// Code 06: one register.
    fn word(addr: u16, value: u16) -> Self {
        let ([a, b], [c, d]) = (addr.to_be_bytes(), value.to_be_bytes());
        Self { bytes: [0x06, a, b, c, d, 0, 0, 0, 0, 0], len: 5 }
    }

    /// Code 16: a 32-bit value in two registers, low word first (spec §3.2), in one request
    /// (all or nothing).
    fn long(addr: u16, value: u32) -> Self {
        let [low, high] = words_low_first(value);
        let ([a, b], [lh, ll], [hh, hl]) = (addr.to_be_bytes(), low.to_be_bytes(), high.to_be_bytes());
        Self { bytes: [0x10, a, b, 0, 2, 4, lh, ll, hh, hl], len: 10 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_an_address_is_a_host() {
        for ok in [
            "192.168.1.50",
            "192.168.1.50:80",
            "127.0.0.1:8080",
            "10.0.2.15",
            "localhost",
            "LOCALHOST:80",
            "[::1]:8080",
            "[fe80::1]",
        ] {
            assert!(host_is_an_address(Some(ok)), "{ok}");
        }
        // A name (DNS rebinding), a malformed address or port, none at all.
        for refused in [
            "attacker.example",
            "attacker.example:80",
            "192.168.1.50.nip.io",
            "192.168.1",
            "192.168.1.256",
            "0300.0250.1.1",
            "192.168.1.50:",
            "192.168.1.50:http",
            "192.168.1.50:65536",
            "192.168.1.50:+80",
            "[::1",
            "[::1]80",
            "[attacker.example]:80",
            "[fe80::1%25eth0]",
            "[]",
            "",
        ] {
            assert!(!host_is_an_address(Some(refused)), "{refused}");
        }
        assert!(!host_is_an_address(None));
    }

    #[test]
    fn decimal_numbers_in_hundredths() {
        for (body, want) in [
            (r#"{"value":1.25}"#, Some(125)),
            (r#"{"value":-2}"#, Some(-200)),
            (r#"{"value":-0.5}"#, Some(-50)),
            (r#" { "value" : 60 } "#, Some(6000)),
            (r#"{"value":1.2}"#, Some(120)),
            (r#"{"value":1.250}"#, None),
            (r#"{"value":1.}"#, None),
            (r#"{"value":.5}"#, None),
            (r#"{"value":1e2}"#, None),
            (r#"{"value":"1"}"#, None),
            (r#"{"value":--1}"#, None),
            (r#"{"value":123456}"#, None),
            (r#"{"other":1}"#, None),
        ] {
            let got = Object::parse(body.as_bytes()).and_then(|o| o.number("value")).and_then(hundredths);
            assert_eq!(got, want, "{body}");
        }
    }

    #[test]
    fn an_answer_that_does_not_fit_is_marked_cut() {
        let mut json = Json::default();
        for _ in 0..MAX_ANSWER / 10 {
            json.push_str("0123456789");
        }
        assert!(!json.cut);
        json.push_str("0123456789");
        json.push('}');
        assert!(json.cut, "a piece that did not fit, and any after it");
    }

    #[test]
    fn thousandths_as_decimals() {
        for (t, want) in [(1200, "1.200"), (-250_000, "-250.000"), (-5, "-0.005"), (0, "0.000")] {
            let mut json = Json::default();
            write_thousandths(&mut json, t).unwrap();
            assert_eq!(json.text.as_str(), want);
        }
    }
}
