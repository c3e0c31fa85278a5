//! The web console's sessions (issue #25, docs/web.md): logins by the challenge-response of
//! the discovery service and the update session (`remodaq_protocol::web`), within the same
//! module-wide guessing budget ([`remodaq_shared::password::AUTH`]), and the check of every signed,
//! state-changing request. No HTTP here: the server hands over the parsed headers and body.

use remodaq_protocol::auth::{same, Credential, KEY_LEN, NONCE_LEN};
use remodaq_protocol::web::{login_message, login_signature, request_signature, session_key, SESSION_ID_LEN};

use remodaq_shared::nonces::Nonces;
use remodaq_shared::password::{Check, AUTH};

/// Sessions live at once; a login beyond them ends the one idle the longest.
pub const SESSIONS: usize = 2;
/// A session ends after this long without a signed request.
pub const IDLE_MS: u64 = 10 * 60 * 1000;
/// A session ends this long after its login, however busy.
pub const MAX_AGE_MS: u64 = 8 * 60 * 60 * 1000;
/// Login challenges handed out and not used yet.
pub const CHALLENGES: usize = 4;
/// A challenge is valid this long.
pub const CHALLENGE_MS: u64 = 30 * 1000;

/// What a login challenge gives the page.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Challenge {
    /// The salt of the module's password.
    pub salt: [u8; 16],
    /// Its PBKDF2 iteration count.
    pub iterations: u32,
    /// The module's nonce for this login.
    pub nonce: [u8; NONCE_LEN],
}

/// A login the page sends.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Login {
    /// The module's nonce, from [`Challenge`].
    pub module_nonce: [u8; NONCE_LEN],
    /// The page's nonce.
    pub page_nonce: [u8; NONCE_LEN],
    /// ClientProof over [`login_message`].
    pub proof: [u8; KEY_LEN],
}

/// A login that succeeded: the session id and the module's signature of it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoggedIn {
    /// The new session.
    pub session: [u8; SESSION_ID_LEN],
    /// [`login_signature`]: the page checks it with its ServerKey.
    pub signature: [u8; KEY_LEN],
}

/// Why a login failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoginError {
    /// The module's nonce is unknown, used, expired or was handed to another address.
    Challenge,
    /// The proof is wrong (counted against the budget).
    Wrong,
    /// Not checked: the guessing budget is spent.
    Limited,
}

/// A state-changing request as the server read it.
#[derive(Clone, Copy, Debug)]
pub struct Signed<'a> {
    /// The method, as sent (`PUT`, `POST`, `DELETE`).
    pub method: &'a str,
    /// The request target, as sent (path and query).
    pub target: &'a str,
    /// The body.
    pub body: &'a [u8],
    /// The session header; `None` when absent or not 16 hex digits.
    pub session: Option<[u8; SESSION_ID_LEN]>,
    /// The counter header; `None` when absent or not a decimal number.
    pub counter: Option<u64>,
    /// The signature header; `None` when absent or not 64 hex digits.
    pub signature: Option<[u8; KEY_LEN]>,
}

/// Why a state-changing request was refused (nothing changed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// No session, counter or signature header (or one that does not parse).
    Unsigned,
    /// No such session, or it ended (idle, evicted, logged out).
    NoSession,
    /// The counter is not above the last one accepted in the session (a replay).
    Stale,
    /// The signature does not match the request (altered, or not signed with the key).
    BadSignature,
    /// A method that is not upper-case letters, or a target with a byte outside `!`..`~`: the
    /// signed form is unambiguous only without them.
    Malformed,
}

/// A state-changing request that passed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Verified {
    /// The session was opened with the factory password (which allows less, docs/security.md).
    pub factory: bool,
}

#[derive(Clone, Copy)]
struct Session {
    id: [u8; SESSION_ID_LEN],
    key: [u8; KEY_LEN],
    /// The last counter accepted (0 before the first request: counters start at 1).
    counter: u64,
    last_ms: u64,
    born_ms: u64,
    /// The password it was opened with (its StoredKey): another password in force ends it.
    stored_key: [u8; KEY_LEN],
    factory: bool,
}

/// The module's web sessions and login challenges.
pub struct Sessions {
    challenges: Nonces<CHALLENGES>,
    sessions: [Option<Session>; SESSIONS],
}

impl Default for Sessions {
    fn default() -> Self {
        Self::new()
    }
}

impl Sessions {
    /// No session, no challenge.
    pub const fn new() -> Self {
        Self { challenges: Nonces::one_per_address(CHALLENGE_MS), sessions: [None; SESSIONS] }
    }

    /// A login challenge for `from`, for the password `credential`; none before the board
    /// seeded the random numbers (the nonce, then the session key, would be predictable).
    pub fn challenge(&mut self, credential: &Credential, from: [u8; 4], now_ms: u64) -> Option<Challenge> {
        if !AUTH.is_seeded() {
            return None;
        }
        let nonce = self.challenges.issue(from, now_ms);
        Some(Challenge { salt: credential.salt, iterations: credential.iterations, nonce })
    }

    /// Checks a login from `from` on the module `mac` against `credential` (the nonce is used
    /// up whatever the outcome); a new session on success, ending the one idle the longest
    /// when [`SESSIONS`] are live.
    pub fn login(
        &mut self,
        credential: &Credential,
        mac: &[u8; 6],
        login: &Login,
        from: [u8; 4],
        now_ms: u64,
    ) -> Result<LoggedIn, LoginError> {
        if !self.challenges.redeem(&login.module_nonce, from, now_ms) {
            return Err(LoginError::Challenge);
        }
        let message = login_message(mac, &login.module_nonce, &login.page_nonce);
        let client_key = match AUTH.check(credential, &message, &login.proof, from, now_ms) {
            Check::Ok(client_key) => client_key,
            Check::Wrong => return Err(LoginError::Wrong),
            Check::Limited => return Err(LoginError::Limited),
        };
        self.expire(now_ms);
        let mut id = [0u8; SESSION_ID_LEN];
        AUTH.random(&login.page_nonce, &mut id);
        let session = Session {
            id,
            key: session_key(&client_key, &login.module_nonce, &login.page_nonce),
            counter: 0,
            last_ms: now_ms,
            born_ms: now_ms,
            stored_key: credential.stored_key,
            factory: credential.is_factory(),
        };
        let slot = (0..SESSIONS).min_by_key(|&i| self.sessions[i].map_or(0, |s| s.last_ms + 1)).unwrap_or(0);
        if let Some(place) = self.sessions.get_mut(slot) {
            *place = Some(session);
        }
        Ok(LoggedIn { session: id, signature: login_signature(&credential.server_key, &message, &id) })
    }

    /// Checks a state-changing request at `now_ms`, with `credential` the password in force:
    /// its session is live and was opened with that password, its counter above the last
    /// accepted and its signature right. On success the counter is taken (the same request can
    /// never pass again) and the session's idle time starts again.
    pub fn verify(&mut self, request: &Signed<'_>, credential: &Credential, now_ms: u64) -> Result<Verified, Refusal> {
        self.expire(now_ms);
        for place in &mut self.sessions {
            if place.is_some_and(|s| s.stored_key != credential.stored_key) {
                *place = None;
            }
        }
        let (Some(id), Some(counter), Some(signature)) = (request.session, request.counter, request.signature) else {
            return Err(Refusal::Unsigned);
        };
        let upper = !request.method.is_empty() && request.method.bytes().all(|b| b.is_ascii_uppercase());
        if !upper || !request.target.bytes().all(|b| (0x21..=0x7E).contains(&b)) {
            return Err(Refusal::Malformed);
        }
        let session = self.sessions.iter_mut().flatten().find(|s| s.id == id).ok_or(Refusal::NoSession)?;
        if counter <= session.counter {
            return Err(Refusal::Stale);
        }
        let expected = request_signature(&session.key, request.method, request.target, counter, request.body);
        if !same(&expected, &signature) {
            return Err(Refusal::BadSignature);
        }
        session.counter = counter;
        session.last_ms = now_ms;
        Ok(Verified { factory: session.factory })
    }

    /// The key of live session `id` (to prove what the module answers to it).
    pub fn key(&self, id: &[u8; SESSION_ID_LEN]) -> Option<[u8; KEY_LEN]> {
        self.sessions.iter().flatten().find(|s| s.id == *id).map(|s| s.key)
    }

    /// Ends session `id` (a signed logout; also when the password changes: [`end_all`](Self::end_all)).
    pub fn end(&mut self, id: &[u8; SESSION_ID_LEN]) {
        for place in &mut self.sessions {
            if place.is_some_and(|s| s.id == *id) {
                *place = None;
            }
        }
    }

    /// Ends every session.
    pub fn end_all(&mut self) {
        self.sessions = [None; SESSIONS];
    }

    /// Sessions live at `now_ms`.
    pub fn live(&mut self, now_ms: u64) -> usize {
        self.expire(now_ms);
        self.sessions.iter().flatten().count()
    }

    fn expire(&mut self, now_ms: u64) {
        for place in &mut self.sessions {
            let ended = |s: Session| {
                now_ms.saturating_sub(s.last_ms) >= IDLE_MS || now_ms.saturating_sub(s.born_ms) >= MAX_AGE_MS
            };
            if place.is_some_and(ended) {
                *place = None;
            }
        }
    }
}
