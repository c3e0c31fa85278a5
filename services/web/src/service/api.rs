//! The state every resource of the API works on ([`Api`]: the module, its sessions, the
//! client) and what a resource answers ([`Answer`]: a status and a [`Json`] text, or a page's
//! file), with the headers every answer carries.

use core::cell::{Cell, RefCell};
use core::fmt::Write as _;

use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, RawMutex};
use embassy_sync::blocking_mutex::Mutex as Blocking;
use embassy_sync::mutex::Mutex;
use embedded_storage_async::nor_flash::NorFlash;
use picoserve::io::Read;
use picoserve::response::{Response, ResponseWriter, StatusCode};
use picoserve::ResponseSent;
use remodaq_shared::identity::Identity;
use remodaq_shared::module::{SettingsAccess, Store};

use crate::sessions::Sessions;

/// The sessions of the module's web console (one set for both connections).
pub type SharedSessions = Blocking<CriticalSectionRawMutex, RefCell<Sessions>>;

/// The module's web sessions.
pub static SESSIONS: SharedSessions = Blocking::new(RefCell::new(Sessions::new()));

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

/// Largest JSON answer, bytes: the 8350's 12 DIs with every field at its longest ("latch
/// falling", a 10-digit counter, a 5-digit frequency, about 130 bytes each) take about 1.6 KB;
/// 150 coils 0.9 KB. Each connection's future holds one (issue #39: the web part's RAM).
pub const MAX_ANSWER: usize = 1792;

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
    pub(crate) text: heapless::String<MAX_ANSWER>,
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
    pub(crate) fn push(&mut self, c: char) {
        let _ = self.write_char(c);
    }

    pub(crate) fn push_str(&mut self, s: &str) {
        let _ = self.write_str(s);
    }
}

/// An answer: a status, and a page's file or the JSON text written into the request's [`Json`]
/// (a resource writes there; a few bytes are returned through each call instead of the 2 KiB
/// text, which each return site would otherwise give a stack slot of its own: issue #39, the
/// stack). Each constructor starts the text anew.
#[derive(Clone, Copy)]
pub struct Answer {
    pub(crate) status: StatusCode,
    /// A page's file instead of the JSON: its type and its gzip-compressed bytes.
    pub(super) page: Option<(&'static str, &'static [u8])>,
}

impl Answer {
    /// `status`, with the text in `out` started anew (the resource writes its JSON there).
    pub(crate) fn new(out: &mut Json, status: StatusCode) -> Self {
        // In place: a new `Json` would be a 2 KiB temporary on the stack.
        out.text.clear();
        out.cut = false;
        Self { status, page: None }
    }

    /// `{"error": what}` (and `"field": field` when one field is at fault).
    pub(crate) fn error(out: &mut Json, status: StatusCode, what: &str, field: Option<&str>) -> Self {
        let a = Self::new(out, status);
        let _ = write!(out, "{{\"error\":\"{what}\"");
        if let Some(field) = field {
            let _ = write!(out, ",\"field\":\"{field}\"");
        }
        out.push('}');
        a
    }

    pub(crate) fn no_content(out: &mut Json) -> Self {
        Self::new(out, StatusCode::NO_CONTENT)
    }

    /// 202: done once the answer is sent (a restart).
    pub(crate) fn accepted(out: &mut Json) -> Self {
        let a = Self::new(out, StatusCode::ACCEPTED);
        out.push_str("{\"restarting\":true}");
        a
    }

    /// A page's file.
    pub(super) fn page(kind: &'static str, gz: &'static [u8]) -> Self {
        Self { status: StatusCode::OK, page: Some((kind, gz)) }
    }

    /// Writes the answer (its JSON text is `json`'s) on `connection`.
    pub(super) async fn write_to<R: Read, W: ResponseWriter<Error = R::Error>>(
        self,
        json: &Json,
        connection: picoserve::response::Connection<'_, R>,
        response_writer: W,
    ) -> Result<ResponseSent, W::Error> {
        // One kind of response for every answer: one copy of picoserve's writer in flash.
        let (status, kind, body, headers): (_, _, &[u8], &[(&str, &str)]) = match self.page {
            Some((kind, gz)) => (self.status, kind, gz, &PAGE_HEADERS),
            None if json.cut => (
                StatusCode::INTERNAL_SERVER_ERROR,
                "application/json",
                b"{\"error\":\"answer too long\"}",
                &JSON_HEADERS,
            ),
            None => (self.status, "application/json", json.text.as_bytes(), &JSON_HEADERS),
        };
        let response = Response::new(status, body).with_content_type(kind).with_headers(headers);
        response_writer.write_response(connection, response).await
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
