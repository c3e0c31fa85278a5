//! The router: which resource answers a request (picoserve's [`PathRouterService`] for
//! [`Api`]), after the checks of its head: a `Host` that names the module by its address, an
//! `Origin` of the module's own for a state-changing request, a target that can be signed whole.

use embassy_sync::blocking_mutex::raw::RawMutex;
use embedded_storage_async::nor_flash::NorFlash;
use picoserve::io::Read;
use picoserve::request::{Path, Request};
use picoserve::response::{ResponseWriter, StatusCode};
use picoserve::routing::PathRouterService;
use picoserve::ResponseSent;
use remodaq_protocol::auth::KEY_LEN;
use remodaq_protocol::resources;
use remodaq_protocol::web::{unhex, HEADER_COUNTER, HEADER_SESSION, HEADER_SIGNATURE, SESSION_ID_LEN};
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::{CommonSettings as _, SettingsAccess};
use remodaq_shared::password::Credential;

use super::api::{Answer, Api, Json};
use super::connection::PAGES;
use super::registers::{MAX_READ_COILS, MAX_READ_REGISTERS};
use crate::sessions::Signed;

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
        // The answer's JSON text, written by the resource (in this request's future).
        let mut json = Json::default();
        let out = &mut json;
        let answer = if !host_is_an_address(header(&parts, "Host")) {
            // DNS rebinding: a hostile page whose name the attacker's DNS turns into the module's
            // address sends its requests with its own name as the Host (docs/web.md).
            Answer::error(out, StatusCode::MISDIRECTED_REQUEST, "reach the module by its address", None)
        } else if let Some((_, kind, gz)) = PAGES.iter().find(|(p, ..)| *p == target).filter(|_| method == "GET") {
            Answer::page(kind, gz)
        } else {
            let query = parts.query().map(|q| q.0);
            let full = full_target(target, query);
            match (request.body_connection.body().read_all().await, full.as_ref()) {
                (Ok(_), None) => Answer::error(out, StatusCode::URI_TOO_LONG, "target too long", None),
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
                    self.route(out, method, target, query, &signed, foreign, &credential).await
                }
                (Err(_), _) => Answer::error(out, StatusCode::PAYLOAD_TOO_LARGE, "body too large", None),
            }
        };
        answer.write_to(&json, request.body_connection.finalize().await?, response_writer).await
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

/// The MQTT settings' resource name, where the build has them (feature `mqtt`); otherwise a name
/// no request path segment can be, so that `/api/v1/mqtt` is no resource (404).
#[cfg(feature = "mqtt")]
const MQTT: &str = "mqtt";
#[cfg(not(feature = "mqtt"))]
const MQTT: &str = "/";

impl<R: RawMutex, M: RegisterMap + SettingsAccess, F: NorFlash> Api<'_, R, M, F> {
    #[allow(clippy::too_many_arguments)]
    async fn route(
        &self,
        out: &mut Json,
        method: &str,
        target: &str,
        query: Option<&str>,
        signed: &Signed<'_>,
        foreign: bool,
        credential: &Credential,
    ) -> Answer {
        let mut segments = target.trim_start_matches('/').split('/');
        let (Some("api"), Some("v1")) = (segments.next(), segments.next()) else {
            return Answer::error(out, StatusCode::NOT_FOUND, "no such resource", None);
        };
        let resource = (segments.next(), segments.next(), segments.next());
        if segments.next().is_some() {
            return Answer::error(out, StatusCode::NOT_FOUND, "no such resource", None);
        }
        let state_changing = !(method.eq_ignore_ascii_case("GET") || method.eq_ignore_ascii_case("HEAD"));
        if state_changing && foreign {
            return Answer::error(out, StatusCode::FORBIDDEN, "request from another origin", None);
        }
        match (method, resource) {
            ("GET", (Some("identity"), None, None)) => self.identity(out),
            ("POST", (Some("session"), Some("challenge"), None)) => self.challenge(out, credential),
            ("POST", (Some("session"), None, None)) => self.login(out, signed.body, credential),
            ("DELETE", (Some("session"), None, None)) => match self.verify(signed, credential) {
                Ok(_) => {
                    if let Some(id) = signed.session {
                        self.sessions.lock(|s| s.borrow_mut().end(&id));
                        crate::firmware::release(&id);
                    }
                    Answer::no_content(out)
                }
                Err(why) => Answer::error(out, StatusCode::UNAUTHORIZED, why, None),
            },
            ("GET", (Some(table @ ("registers" | "coils")), Some(addr), None)) => {
                let Ok(addr) = addr.parse::<u16>() else {
                    return Answer::error(out, StatusCode::BAD_REQUEST, "not an address", Some("address"));
                };
                let registers = table == "registers";
                match count(query, if registers { MAX_READ_REGISTERS } else { MAX_READ_COILS }) {
                    Some(n) => self.read(out, registers, addr, n).await,
                    None => Answer::error(out, StatusCode::BAD_REQUEST, "count must be 1 to the limit", Some("count")),
                }
            }
            ("PUT", (Some(table @ ("registers" | "coils")), Some(addr), None)) => {
                let Ok(addr) = addr.parse::<u16>() else {
                    return Answer::error(out, StatusCode::BAD_REQUEST, "not an address", Some("address"));
                };
                if let Err(why) = self.verify(signed, credential) {
                    return Answer::error(out, StatusCode::UNAUTHORIZED, why, None);
                }
                self.write(out, table == "registers", addr, signed.body).await
            }
            ("GET", (Some("network"), None, None)) => self.network(out).await,
            ("GET", (Some("firmware"), None, None)) => self.firmware(out),
            ("POST", (Some("firmware"), None | Some("finish"), None)) | ("PUT", (Some("firmware"), Some(_), None)) => {
                let verified = match self.verify(signed, credential) {
                    Ok(verified) => verified,
                    Err(why) => return Answer::error(out, StatusCode::UNAUTHORIZED, why, None),
                };
                // As the update service: not with the factory password (docs/update.md).
                if verified.factory {
                    return Answer::error(out, StatusCode::FORBIDDEN, "set a password first", None);
                }
                let session = signed.session.unwrap_or_default();
                match (method, resource.1) {
                    ("POST", None) => self.firmware_begin(out, session, signed.body).await,
                    ("POST", Some(_)) => self.firmware_finish(out, session).await,
                    (_, Some(offset)) => self.firmware_write(out, session, offset, signed.body).await,
                    _ => Answer::error(out, StatusCode::METHOD_NOT_ALLOWED, "method not allowed here", None),
                }
            }
            (method @ ("PUT" | "GET"), (Some(name @ ("network" | "access" | "password" | MQTT)), None, None))
            | (method @ "PUT", (Some(name @ MQTT), Some("ca" | "credentials"), None))
            | (method @ "POST", (Some(name @ ("restart" | "password")), None | Some("key"), None)) => {
                // Reading the allow-list needs a session too (discovery shows it only with the
                // password); every other read here is open.
                let verified = match self.verify(signed, credential) {
                    Ok(verified) => verified,
                    Err(why) => return Answer::error(out, StatusCode::UNAUTHORIZED, why, None),
                };
                match (method, name, resource.1) {
                    ("PUT", "network", _) => self.set_network(out, signed.body).await,
                    ("GET", "access", _) => self.access(out).await,
                    // As discovery: the factory password, which anyone knows, does not restrict
                    // who may write (docs/security.md).
                    ("PUT", "access", _) if verified.factory => {
                        Answer::error(out, StatusCode::FORBIDDEN, "set a password first", None)
                    }
                    ("PUT", "access", _) => self.set_access(out, signed.body).await,
                    #[cfg(feature = "mqtt")]
                    ("GET", "mqtt", _) => self.mqtt(out).await,
                    // Output commands from a broker: not on a module anyone may log in to.
                    #[cfg(feature = "mqtt")]
                    ("PUT", "mqtt", _) if verified.factory => {
                        Answer::error(out, StatusCode::FORBIDDEN, "set a password first", None)
                    }
                    #[cfg(feature = "mqtt")]
                    ("PUT", "mqtt", Some("ca")) => self.set_mqtt_ca(out, signed.body).await,
                    #[cfg(feature = "mqtt")]
                    ("PUT", "mqtt", Some(_)) => {
                        self.set_mqtt_credentials(out, signed.session.unwrap_or_default(), signed.body).await
                    }
                    #[cfg(feature = "mqtt")]
                    ("PUT", "mqtt", None) => self.set_mqtt(out, signed.body).await,
                    // A verified request names its session.
                    ("POST", "password", Some(_)) => self.password_key(out, signed.session.unwrap_or_default()),
                    ("PUT", "password", _) => {
                        self.set_password(out, signed.session.unwrap_or_default(), signed.body).await
                    }
                    ("POST", "restart", None) => self.restart(out),
                    _ => Answer::error(out, StatusCode::METHOD_NOT_ALLOWED, "method not allowed here", None),
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
            ) => Answer::error(out, StatusCode::METHOD_NOT_ALLOWED, "method not allowed here", None),
            (_, (Some(name), a, b)) => {
                let Some(r) = resources::of(self.identity.model).iter().find(|r| r.name == name) else {
                    return Answer::error(out, StatusCode::NOT_FOUND, "no such resource", None);
                };
                // A list's item: `/{n}`; a field to write: the last segment.
                let (item, field) = if r.count > 0 { (a, b) } else { (None, a.or(b).filter(|_| b.is_none())) };
                let n = match item.map(|n| n.parse::<u16>().ok().filter(|n| *n < r.count)) {
                    Some(None) => return Answer::error(out, StatusCode::NOT_FOUND, "no such item", Some("item")),
                    Some(Some(n)) => Some(n),
                    None => None,
                };
                match (method, field) {
                    ("GET", None) => self.show(out, r, n).await,
                    ("PUT", Some(field)) => {
                        let Some(f) = r.field(field) else {
                            return Answer::error(out, StatusCode::NOT_FOUND, "no such field", Some("field"));
                        };
                        if r.count > 0 && n.is_none() {
                            return Answer::error(out, StatusCode::NOT_FOUND, "no such item", Some("item"));
                        }
                        if let Err(why) = self.verify(signed, credential) {
                            return Answer::error(out, StatusCode::UNAUTHORIZED, why, None);
                        }
                        self.change(out, f, n.unwrap_or(0), signed.body).await
                    }
                    _ => Answer::error(out, StatusCode::METHOD_NOT_ALLOWED, "method not allowed here", None),
                }
            }
            _ => Answer::error(out, StatusCode::NOT_FOUND, "no such resource", None),
        }
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
}
