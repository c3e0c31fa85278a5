//! The login resources: the module's identity (`GET /api/v1/identity`), a login's challenge
//! and the login (`POST /api/v1/session/challenge`, `POST /api/v1/session`), and the signature
//! check every state-changing request passes.

use core::fmt::Write as _;

use embassy_sync::blocking_mutex::raw::RawMutex;
use embedded_storage_async::nor_flash::NorFlash;
use picoserve::response::StatusCode;
use remodaq_protocol::auth::{KEY_LEN, NONCE_LEN};
use remodaq_protocol::web::{hex, unhex, SESSION_ID_LEN};
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::SettingsAccess;
use remodaq_shared::password::Credential;

use super::api::{Answer, Api, Json};
use crate::sessions::{Login, LoginError, Refusal, Signed, Verified};
use remodaq_shared::json::Object;

impl<R: RawMutex, M: RegisterMap + SettingsAccess, F: NorFlash> Api<'_, R, M, F> {
    pub(super) fn identity(&self, out: &mut Json) -> Answer {
        let id = &self.identity;
        let a = Answer::new(out, StatusCode::OK);
        let mut mac = [0u8; 12];
        let _ = write!(
            out,
            "{{\"model\":\"{:04X}\",\"name\":\"{}\",\"firmware\":\"{:04X}\",\"mac\":\"{}\"}}",
            id.model,
            id.name,
            id.version,
            hex(&id.mac, &mut mac).unwrap_or("")
        );
        a
    }

    pub(super) fn challenge(&self, out: &mut Json, credential: &Credential) -> Answer {
        let now = (self.now_ms)();
        let Some(c) = self.sessions.lock(|s| s.borrow_mut().challenge(credential, self.peer, now)) else {
            return Answer::error(out, StatusCode::SERVICE_UNAVAILABLE, "the module is not ready for logins", None);
        };
        let (mut salt, mut nonce) = ([0u8; 32], [0u8; 2 * NONCE_LEN]);
        let a = Answer::new(out, StatusCode::OK);
        let _ = write!(
            out,
            "{{\"salt\":\"{}\",\"iterations\":{},\"nonce\":\"{}\"}}",
            hex(&c.salt, &mut salt).unwrap_or(""),
            c.iterations,
            hex(&c.nonce, &mut nonce).unwrap_or("")
        );
        a
    }

    pub(super) fn login(&self, out: &mut Json, body: &[u8], credential: &Credential) -> Answer {
        let fields = Object::parse(body).and_then(|o| Some((o.str("nonce")?, o.str("page_nonce")?, o.str("proof")?)));
        let Some((nonce, page_nonce, proof)) = fields else {
            return Answer::error(out, StatusCode::BAD_REQUEST, "expected {nonce, page_nonce, proof}", None);
        };
        let (Some(module_nonce), Some(page_nonce), Some(proof)) =
            (unhex(nonce), unhex(page_nonce), unhex::<KEY_LEN>(proof))
        else {
            return Answer::error(out, StatusCode::BAD_REQUEST, "nonces are 32 hex digits, the proof 64", None);
        };
        let now = (self.now_ms)();
        let login = Login { module_nonce, page_nonce, proof };
        let mac = self.identity.mac;
        match self.sessions.lock(|s| s.borrow_mut().login(credential, &mac, &login, self.peer, now)) {
            Ok(done) => {
                let (mut id, mut signature) = ([0u8; 2 * SESSION_ID_LEN], [0u8; 2 * KEY_LEN]);
                let a = Answer::new(out, StatusCode::OK);
                let _ = write!(
                    out,
                    "{{\"session\":\"{}\",\"signature\":\"{}\"}}",
                    hex(&done.session, &mut id).unwrap_or(""),
                    hex(&done.signature, &mut signature).unwrap_or("")
                );
                a
            }
            Err(LoginError::Challenge) => {
                Answer::error(out, StatusCode::UNAUTHORIZED, "challenge unknown, used or expired", Some("nonce"))
            }
            Err(LoginError::Wrong) => Answer::error(out, StatusCode::UNAUTHORIZED, "wrong password", None),
            Err(LoginError::Limited) => {
                Answer::error(out, StatusCode::TOO_MANY_REQUESTS, "too many wrong passwords: wait", None)
            }
        }
    }

    /// The signature check of a state-changing request, against the password in force; why
    /// it was refused.
    pub(super) fn verify(&self, signed: &Signed<'_>, credential: &Credential) -> Result<Verified, &'static str> {
        let now = (self.now_ms)();
        self.sessions.lock(|s| s.borrow_mut().verify(signed, credential, now)).map_err(|refusal| match refusal {
            Refusal::Unsigned => "unsigned",
            Refusal::NoSession => "no session",
            Refusal::Stale => "stale counter",
            Refusal::BadSignature => "bad signature",
            Refusal::Malformed => "malformed method or target",
        })
    }
}
