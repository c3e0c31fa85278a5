//! A firmware update through the web console (docs/web.md, "Firmware"): the page sends the
//! signed image file (`remodaq sign`) in signed requests of a logged-in session, a chunk each,
//! and the board's update task writes, verifies and marks it as a session of the update
//! service would (`crate::update`): the same header checks, the same anti-rollback counter, the
//! same signature check against the module's key. Nothing is marked before the whole image
//! verified; an upload cut anywhere leaves the running image and its settings as they were.
//!
//! - `GET /api/v1/firmware`: the running version, whether this module takes updates here, the
//!   chunk size.
//! - `POST /api/v1/firmware` (signed, the header's bytes): a new upload of this session.
//! - `PUT /api/v1/firmware/{offset}` (signed, the bytes from `offset`): the next chunk.
//! - `POST /api/v1/firmware/finish` (signed): verify and mark; the module restarts into it.

use core::cell::Cell;
use core::fmt::Write as _;

use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, RawMutex};
use embassy_sync::blocking_mutex::Mutex as Blocking;
use embedded_storage_async::nor_flash::NorFlash;
use picoserve::response::StatusCode;
use remodaq_protocol::web::SESSION_ID_LEN;

use crate::service::api::{Answer, Api, Json};
use remodaq_protocol::update::{Status, HEADER_LEN};
use remodaq_shared::diagnostics::{Security, DIAGNOSTICS};
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::SettingsAccess;
use remodaq_shared::upload::{WebDone, WebStep, WEB, WEB_CHUNK};

/// A session that owns the upload under way, and when it last sent a step.
type Owner = Option<([u8; SESSION_ID_LEN], u64)>;

/// The session whose upload is under way, and when it last sent a step.
static OWNER: Blocking<CriticalSectionRawMutex, Cell<Owner>> = Blocking::new(Cell::new(None));

/// A session that logs out gives up its upload: another may begin one at once.
pub(super) fn release(session: &[u8; SESSION_ID_LEN]) {
    OWNER.lock(|o| {
        if matches!(o.get(), Some((owner, _)) if owner == *session) {
            o.set(None);
        }
    });
}

/// An upload with no step for this long may be replaced by another session's.
const ABANDONED_MS: u64 = 30_000;

impl<R: RawMutex, M: RegisterMap + SettingsAccess, F: NorFlash> Api<'_, R, M, F> {
    /// `GET /api/v1/firmware`.
    pub(super) fn firmware(&self, out: &mut Json) -> Answer {
        let a = Answer::new(out, StatusCode::OK);
        let _ = write!(
            out,
            "{{\"firmware\":\"{:04X}\",\"updates\":{},\"chunk\":{}}}",
            self.identity.version,
            WEB.is_served(),
            WEB_CHUNK
        );
        a
    }

    /// `POST /api/v1/firmware` (signed, not with the factory password): `body` is the image's
    /// header; the upload begins, replacing one of this session's or one abandoned.
    pub(super) async fn firmware_begin(&self, out: &mut Json, session: [u8; SESSION_ID_LEN], body: &[u8]) -> Answer {
        let Ok(header) = <[u8; HEADER_LEN]>::try_from(body) else {
            return Answer::error(out, StatusCode::BAD_REQUEST, "expected the image's header", Some("header"));
        };
        let now = (self.now_ms)();
        let taken = OWNER.lock(|o| match o.get() {
            Some((other, last)) if other != session && now.saturating_sub(last) < ABANDONED_MS => false,
            _ => {
                o.set(Some((session, now)));
                true
            }
        });
        if !taken {
            return Answer::error(out, StatusCode::CONFLICT, "another upload is under way", None);
        }
        match WEB.ask(WebStep::Begin(header)).await {
            Some(Ok(WebDone::Begun(h))) => {
                let a = Answer::new(out, StatusCode::OK);
                let _ = write!(out, "{{\"firmware\":\"{:04X}\",\"length\":{}}}", h.version, h.length);
                a
            }
            other => {
                // No upload under way: this session's was refused (or never began).
                OWNER.lock(|o| o.set(None));
                self.refused(out, other)
            }
        }
    }

    /// `PUT /api/v1/firmware/{offset}` (signed): the next chunk of this session's upload.
    pub(super) async fn firmware_write(
        &self,
        out: &mut Json,
        session: [u8; SESSION_ID_LEN],
        offset: &str,
        body: &[u8],
    ) -> Answer {
        let Ok(offset) = offset.parse::<u32>() else {
            return Answer::error(out, StatusCode::BAD_REQUEST, "not an offset", Some("offset"));
        };
        if body.is_empty() || body.len() > WEB_CHUNK {
            return Answer::error(out, StatusCode::BAD_REQUEST, "1 to 512 bytes a chunk", Some("body"));
        }
        if !self.owns_upload(session) {
            return Answer::error(out, StatusCode::CONFLICT, "no upload of this session", None);
        }
        let mut data = [0u8; WEB_CHUNK];
        data[..body.len()].copy_from_slice(body);
        match WEB.ask(WebStep::Write { offset, len: body.len(), data }).await {
            Some(Ok(WebDone::Written(n))) => {
                let a = Answer::new(out, StatusCode::OK);
                let _ = write!(out, "{{\"received\":{n}}}");
                a
            }
            // Out of order, or the wrong length for this place: nothing written.
            Some(Err(Status::Invalid)) => {
                Answer::error(out, StatusCode::CONFLICT, "not the next chunk", Some("offset"))
            }
            other => self.ended(out, other),
        }
    }

    /// `POST /api/v1/firmware/finish` (signed): verify and mark this session's upload; the
    /// connection's task restarts the module into it once the answer is sent.
    pub(super) async fn firmware_finish(&self, out: &mut Json, session: [u8; SESSION_ID_LEN]) -> Answer {
        if !self.owns_upload(session) {
            return Answer::error(out, StatusCode::CONFLICT, "no upload of this session", None);
        }
        match WEB.ask(WebStep::Finish).await {
            Some(Ok(WebDone::Updated(h))) => {
                OWNER.lock(|o| o.set(None));
                self.restart.set(true);
                let a = Answer::new(out, StatusCode::OK);
                let _ = write!(out, "{{\"firmware\":\"{:04X}\",\"restarting\":true}}", h.version);
                a
            }
            Some(Err(Status::Invalid)) => Answer::error(out, StatusCode::CONFLICT, "the image is not all sent", None),
            other => self.ended(out, other),
        }
    }

    /// The answer to a write or a finish that ended the upload (the update task dropped it, or
    /// a session of the update service began since): the session owns none any more, and
    /// another may begin at once.
    fn ended(&self, out: &mut Json, done: Option<Result<WebDone, Status>>) -> Answer {
        // Not taken in time (`None`): the upload may still be there; the owner keeps it.
        if done.is_some() {
            OWNER.lock(|o| o.set(None));
        }
        match done {
            Some(Ok(WebDone::NoUpload)) => Answer::error(out, StatusCode::CONFLICT, "no upload of this session", None),
            other => self.refused(out, other),
        }
    }

    /// Whether `session` has the upload under way (its idle time then starts again).
    fn owns_upload(&self, session: [u8; SESSION_ID_LEN]) -> bool {
        let now = (self.now_ms)();
        OWNER.lock(|o| match o.get() {
            Some((owner, _)) if owner == session => {
                o.set(Some((owner, now)));
                true
            }
            _ => false,
        })
    }

    /// The answer to a step refused by the update task, or not taken. A refusal counts in the
    /// security counters, as the update service's do.
    fn refused(&self, out: &mut Json, done: Option<Result<WebDone, Status>>) -> Answer {
        let status = match done {
            None if !WEB.is_served() => {
                return Answer::error(out, StatusCode::SERVICE_UNAVAILABLE, "this module takes no updates here", None);
            }
            None => return Answer::error(out, StatusCode::SERVICE_UNAVAILABLE, "the update task did not answer", None),
            Some(Ok(_)) => return Answer::error(out, StatusCode::INTERNAL_SERVER_ERROR, "unexpected step", None),
            Some(Err(status)) => status,
        };
        DIAGNOSTICS.security(Security::UpdateRefusal, self.peer);
        match status {
            Status::Invalid => Answer::error(
                out,
                StatusCode::UNPROCESSABLE_ENTITY,
                "not an image for this module (model, size or format)",
                Some("header"),
            ),
            Status::Downgrade => Answer::error(
                out,
                StatusCode::UNPROCESSABLE_ENTITY,
                "the image's security counter is below the module's (an older release)",
                Some("header"),
            ),
            Status::BadSignature => Answer::error(
                out,
                StatusCode::UNPROCESSABLE_ENTITY,
                "the signature does not match (another key, or a changed file)",
                Some("signature"),
            ),
            _ => Answer::error(out, StatusCode::SERVICE_UNAVAILABLE, "the module could not write the update", None),
        }
    }
}
