//! The web console's sessions (docs/web.md, "Authentication"), with the page's side computed
//! as docs/web.md tells a page to: PBKDF2 for ClientKey (`auth::derive`, checked against RFC
//! 7677 in the protocol crate), the proof, the session key, the signature of each request.

use std::sync::Mutex;

#[path = "../../../shared/tests/common/mod.rs"]
mod common;
#[path = "common/memory_connection.rs"]
mod memory_connection;

use remodaq_protocol::auth::{client_proof, derive, server_signature, Credential, KEY_LEN, NONCE_LEN};
use remodaq_protocol::web::{login_message, request_signature, session_key, SESSION_ID_LEN};
use remodaq_shared::password::AUTH;
use remodaq_web::{Login, LoginError, Refusal, Sessions, Signed, Verified};

// The rules these tests hold the sessions to, as docs/web.md ("Authentication") gives them: the
// figures are the document's, never the code's constants (a constant changed by mistake must
// fail here).
/// "at most 2 live; a third login ends the one idle the longest".
const LIVE: usize = 2;
/// "A session ends after 10 minutes without a signed request".
const IDLE: u64 = 10 * 60_000;
/// "8 hours after its login however busy".
const MAX_AGE: u64 = 8 * 3_600_000;
/// "a 16-byte nonce for this address, valid 30 s, usable once".
const CHALLENGE_LIFE: u64 = 30_000;
/// "(4 outstanding; the oldest is forgotten)".
const OUTSTANDING: usize = 4;

/// The module's guessing budget is one static: these tests take turns.
static TURN: Mutex<()> = Mutex::new(());

const MAC: [u8; 6] = [0x02, 0, 0, 0x83, 0x50, 1];
const PAGE: [u8; 4] = [192, 168, 0, 10];
const PASSWORD: &[u8] = b"correct horse";
const SALT: [u8; 16] = *b"sixteen bytes!!!";

fn turn() -> std::sync::MutexGuard<'static, ()> {
    let guard = TURN.lock().unwrap_or_else(|e| e.into_inner());
    AUTH.seed(&[7; 32]);
    AUTH.reset_budget_for_tests();
    guard
}

/// The page: logs in with `password` from `from`; its session id and key, or the error.
fn log_in(
    sessions: &mut Sessions,
    credential: &Credential,
    password: &[u8],
    from: [u8; 4],
    now_ms: u64,
) -> Result<([u8; SESSION_ID_LEN], [u8; KEY_LEN]), LoginError> {
    let challenge = sessions.challenge(credential, from, now_ms).expect("seeded");
    let page_nonce = [0x5A; NONCE_LEN];
    let (client_key, page_credential) = derive(password, &challenge.salt, challenge.iterations);
    let message = login_message(&MAC, &challenge.nonce, &page_nonce);
    let login = Login { module_nonce: challenge.nonce, page_nonce, proof: client_proof(&client_key, &message) };
    let done = sessions.login(credential, &MAC, &login, from, now_ms)?;
    // The page knows the module answered: the signature is over the login and the id, with
    // the ServerKey it derived itself.
    let mut signed = message.to_vec();
    signed.push(&done.session);
    assert_eq!(done.signature, server_signature(&page_credential.server_key, &signed));
    Ok((done.session, session_key(&client_key, &challenge.nonce, &page_nonce)))
}

fn signed<'a>(
    session: [u8; SESSION_ID_LEN],
    key: &[u8; KEY_LEN],
    method: &'a str,
    target: &'a str,
    counter: u64,
    body: &'a [u8],
) -> Signed<'a> {
    Signed {
        method,
        target,
        body,
        session: Some(session),
        counter: Some(counter),
        signature: Some(request_signature(key, method, target, counter, body)),
    }
}

fn credential() -> Credential {
    derive(PASSWORD, &SALT, 4096).1
}

#[test]
fn a_signed_request_passes_once_and_nothing_else_does() {
    let _turn = turn();
    let credential = credential();
    let mut sessions = Sessions::new();
    let (id, key) = log_in(&mut sessions, &credential, PASSWORD, PAGE, 0).expect("the right password logs in");
    let body = br#"{"on":true}"#;
    let request = signed(id, &key, "PUT", "/api/v1/do/0", 1, body);
    assert_eq!(sessions.verify(&request, &credential, 10), Ok(Verified { factory: false }));
    // Recorded and sent again: refused (its counter was taken).
    assert_eq!(sessions.verify(&request, &credential, 20), Err(Refusal::Stale));
    // A counter at or below the last one, even signed right: refused.
    assert_eq!(
        sessions.verify(&signed(id, &key, "PUT", "/api/v1/do/0", 1, body), &credential, 30),
        Err(Refusal::Stale)
    );
    // Altered: the body, the path or the method changed after signing.
    let mut altered = signed(id, &key, "PUT", "/api/v1/do/0", 2, body);
    altered.body = br#"{"on":false}"#;
    assert_eq!(sessions.verify(&altered, &credential, 40), Err(Refusal::BadSignature));
    altered = signed(id, &key, "PUT", "/api/v1/do/0", 2, body);
    altered.target = "/api/v1/do/1";
    assert_eq!(sessions.verify(&altered, &credential, 40), Err(Refusal::BadSignature));
    altered = signed(id, &key, "PUT", "/api/v1/do/0", 2, body);
    altered.method = "DELETE";
    assert_eq!(sessions.verify(&altered, &credential, 40), Err(Refusal::BadSignature));
    // Signed with another key (a page that never logged in): refused.
    assert_eq!(
        sessions.verify(&signed(id, &[1; KEY_LEN], "PUT", "/api/v1/do/0", 2, body), &credential, 40),
        Err(Refusal::BadSignature)
    );
    // No signature, or a session the module never gave.
    let mut unsigned = signed(id, &key, "PUT", "/api/v1/do/0", 2, body);
    unsigned.signature = None;
    assert_eq!(sessions.verify(&unsigned, &credential, 40), Err(Refusal::Unsigned));
    assert_eq!(
        sessions.verify(&signed([9; 8], &key, "PUT", "/api/v1/do/0", 2, body), &credential, 40),
        Err(Refusal::NoSession)
    );
    // The next counter, signed right, passes; a failed attempt did not take it.
    assert_eq!(
        sessions.verify(&signed(id, &key, "PUT", "/api/v1/do/0", 2, body), &credential, 50),
        Ok(Verified { factory: false })
    );
}

#[test]
fn wrong_passwords_count_against_the_module_wide_budget() {
    let _turn = turn();
    let credential = credential();
    let mut sessions = Sessions::new();
    // A source's share of the budget is 5 (password.rs): the 6th guess is not even checked.
    for _ in 0..5 {
        assert_eq!(log_in(&mut sessions, &credential, b"wrong password", PAGE, 0), Err(LoginError::Wrong));
    }
    assert_eq!(log_in(&mut sessions, &credential, b"wrong password", PAGE, 0), Err(LoginError::Limited));
    assert_eq!(log_in(&mut sessions, &credential, PASSWORD, PAGE, 0), Err(LoginError::Limited));
    assert_eq!(sessions.live(0), 0);
}

#[test]
fn a_challenge_is_used_once_by_its_address_within_30_s() {
    let _turn = turn();
    let credential = credential();
    let mut sessions = Sessions::new();
    let page_nonce = [1; NONCE_LEN];
    let login_for = |nonce: [u8; NONCE_LEN]| {
        let (client_key, _) = derive(PASSWORD, &SALT, 4096);
        Login {
            module_nonce: nonce,
            page_nonce,
            proof: client_proof(&client_key, &login_message(&MAC, &nonce, &page_nonce)),
        }
    };
    // Recorded by a sniffer and sent again: the nonce is spent.
    let nonce = sessions.challenge(&credential, PAGE, 0).expect("seeded").nonce;
    let login = login_for(nonce);
    assert!(sessions.login(&credential, &MAC, &login, PAGE, 10).is_ok());
    assert_eq!(sessions.login(&credential, &MAC, &login, PAGE, 20), Err(LoginError::Challenge));
    // Sent from another address than the one that asked.
    let nonce = sessions.challenge(&credential, PAGE, 0).expect("seeded").nonce;
    assert_eq!(sessions.login(&credential, &MAC, &login_for(nonce), [192, 168, 0, 66], 10), Err(LoginError::Challenge));
    // Too late: 30 s after it was handed out; just before, it is still good.
    let nonce = sessions.challenge(&credential, PAGE, 0).expect("seeded").nonce;
    assert_eq!(sessions.login(&credential, &MAC, &login_for(nonce), PAGE, CHALLENGE_LIFE), Err(LoginError::Challenge));
    let nonce = sessions.challenge(&credential, PAGE, 1000).expect("seeded").nonce;
    assert!(sessions.login(&credential, &MAC, &login_for(nonce), PAGE, 1000 + CHALLENGE_LIFE - 1).is_ok());
    // Made for another module (its MAC is in the proof).
    let nonce = sessions.challenge(&credential, PAGE, 0).expect("seeded").nonce;
    let (client_key, _) = derive(PASSWORD, &SALT, 4096);
    let other = [0x02, 0, 0, 0x83, 0x18, 9];
    let login = Login {
        module_nonce: nonce,
        page_nonce,
        proof: client_proof(&client_key, &login_message(&other, &nonce, &page_nonce)),
    };
    assert_eq!(sessions.login(&credential, &MAC, &login, PAGE, 10), Err(LoginError::Wrong));
}

#[test]
fn sessions_end_when_idle_and_at_most_two_live() {
    let _turn = turn();
    let credential = credential();
    let mut sessions = Sessions::new();
    let (a, key_a) = log_in(&mut sessions, &credential, PASSWORD, PAGE, 0).expect("login a");
    let (b, key_b) = log_in(&mut sessions, &credential, PASSWORD, PAGE, 1000).expect("login b");
    assert_eq!(sessions.live(1000), LIVE);
    // a is used, so b is now the one idle the longest: a third login ends b.
    assert_eq!(
        sessions.verify(&signed(a, &key_a, "POST", "/x", 1, b""), &credential, 2000),
        Ok(Verified { factory: false })
    );
    let (c, key_c) = log_in(&mut sessions, &credential, PASSWORD, PAGE, 3000).expect("login c");
    assert_eq!(sessions.live(3000), LIVE);
    assert_eq!(sessions.verify(&signed(b, &key_b, "POST", "/x", 1, b""), &credential, 3000), Err(Refusal::NoSession));
    // Idle for 10 minutes: ended; a moment less, still live.
    assert_eq!(
        sessions.verify(&signed(c, &key_c, "POST", "/x", 1, b""), &credential, 3000 + IDLE - 1),
        Ok(Verified { factory: false })
    );
    assert_eq!(
        sessions.verify(&signed(a, &key_a, "POST", "/x", 2, b""), &credential, 2000 + IDLE),
        Err(Refusal::NoSession)
    );
    // Logged out.
    sessions.end(&c);
    assert_eq!(
        sessions.verify(&signed(c, &key_c, "POST", "/x", 2, b""), &credential, 3000 + IDLE),
        Err(Refusal::NoSession)
    );
    assert_eq!(sessions.live(3000 + IDLE), 0);
}

#[test]
fn a_new_password_ends_every_session_and_none_lives_past_8_hours() {
    let _turn = turn();
    let credential = credential();
    let mut sessions = Sessions::new();
    let (id, key) = log_in(&mut sessions, &credential, PASSWORD, PAGE, 0).expect("login");
    // Busy all along (a signed request every minute): live until 8 hours after the login, a
    // moment less still passes; at 8 hours, ended.
    let mut counter = 0;
    let mut now = 0;
    while now + 60_000 < MAX_AGE {
        now += 60_000;
        counter += 1;
        assert_eq!(
            sessions.verify(&signed(id, &key, "POST", "/x", counter, b""), &credential, now),
            Ok(Verified { factory: false }),
            "{now} ms after the login"
        );
    }
    counter += 1;
    assert_eq!(
        sessions.verify(&signed(id, &key, "POST", "/x", counter, b""), &credential, MAX_AGE - 1),
        Ok(Verified { factory: false })
    );
    assert_eq!(
        sessions.verify(&signed(id, &key, "POST", "/x", counter + 1, b""), &credential, MAX_AGE),
        Err(Refusal::NoSession)
    );
    // Another password in force: the session opened with the old one ends.
    let (id, key) = log_in(&mut sessions, &credential, PASSWORD, PAGE, 0).expect("login");
    let changed = derive(b"another password", &SALT, 4096).1;
    assert_eq!(sessions.verify(&signed(id, &key, "POST", "/x", 1, b""), &changed, 10), Err(Refusal::NoSession));
    assert_eq!(sessions.verify(&signed(id, &key, "POST", "/x", 2, b""), &credential, 20), Err(Refusal::NoSession));
}

#[test]
fn the_factory_password_is_marked_and_junk_in_the_signed_form_refused() {
    let _turn = turn();
    let factory = Credential::FACTORY;
    let mut sessions = Sessions::new();
    let (id, key) = log_in(&mut sessions, &factory, b"remodaq", PAGE, 0).expect("the factory password logs in");
    assert_eq!(
        sessions.verify(&signed(id, &key, "PUT", "/api/v1/coils/0", 1, b""), &factory, 1),
        Ok(Verified { factory: true })
    );
    // A line feed or a space in the target, a lower-case method: refused before the signature.
    for (method, target) in [("PUT", "/a\n5"), ("PUT", "/a b"), ("put", "/a"), ("", "/a")] {
        let request = signed(id, &key, method, target, 2, b"");
        assert_eq!(sessions.verify(&request, &factory, 2), Err(Refusal::Malformed), "{method:?} {target:?}");
    }
}

#[test]
fn a_challenge_read_on_the_wire_cannot_be_burnt_and_a_loop_pushes_out_only_its_own() {
    let _turn = turn();
    let credential = credential();
    let mut sessions = Sessions::new();
    let attacker = [192, 168, 0, 66];
    let owner = sessions.challenge(&credential, PAGE, 0).expect("seeded").nonce;
    // The attacker sends a junk login with the owner's nonce, and asks for challenges in a loop.
    let junk = Login { module_nonce: owner, page_nonce: [0; NONCE_LEN], proof: [0; KEY_LEN] };
    assert_eq!(sessions.login(&credential, &MAC, &junk, attacker, 1), Err(LoginError::Challenge));
    for t in 0..20 {
        sessions.challenge(&credential, attacker, t);
    }
    // The owner's login still goes through with its nonce.
    let page_nonce = [3; NONCE_LEN];
    let (client_key, _) = derive(PASSWORD, &SALT, 4096);
    let proof = client_proof(&client_key, &login_message(&MAC, &owner, &page_nonce));
    let login = Login { module_nonce: owner, page_nonce, proof };
    assert!(sessions.login(&credential, &MAC, &login, PAGE, 25).is_ok());
}

/// docs/web.md: "4 outstanding; the oldest is forgotten". Five addresses ask in turn: the first
/// one's nonce is forgotten, the four others' still log in (a table of 3 would lose the second
/// too, one of 64 would keep the first).
#[test]
fn four_challenges_are_outstanding_and_the_oldest_is_forgotten() {
    let _turn = turn();
    let credential = credential();
    let mut sessions = Sessions::new();
    let addresses: Vec<[u8; 4]> = (1..=OUTSTANDING as u8 + 1).map(|i| [192, 168, 0, 20 + i]).collect();
    let nonces: Vec<_> = addresses
        .iter()
        .enumerate()
        .map(|(i, &from)| sessions.challenge(&credential, from, i as u64).expect("seeded").nonce)
        .collect();
    let page_nonce = [4; NONCE_LEN];
    let (client_key, _) = derive(PASSWORD, &SALT, 4096);
    let login_for = |nonce: [u8; NONCE_LEN]| Login {
        module_nonce: nonce,
        page_nonce,
        proof: client_proof(&client_key, &login_message(&MAC, &nonce, &page_nonce)),
    };
    let now = 100;
    assert_eq!(
        sessions.login(&credential, &MAC, &login_for(nonces[0]), addresses[0], now),
        Err(LoginError::Challenge),
        "the oldest of 5 is forgotten"
    );
    for (nonce, from) in nonces.iter().zip(&addresses).skip(1) {
        let result = sessions.login(&credential, &MAC, &login_for(*nonce), *from, now);
        assert!(result.is_ok(), "{from:?}: {result:?}");
    }
}

/// docs/web.md, "Firmware": "One upload at a time, owned by the session that began it; another
/// session may begin its own once the first has sent nothing for 30 s (409 before that), or at
/// once when the first logged out". Through the console's HTTP service (picoserve and the API,
/// as a board serves them) on a clock the test sets, with a task in the update task's place
/// serving `upload::WEB`: a refused begin must not reach it (it would overwrite the owner's
/// partition).
mod one_upload_at_a_time {
    use core::cell::{Cell, RefCell};
    use std::sync::atomic::{AtomicU64, Ordering};

    use embassy_futures::select::{select, Either};
    use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, NoopRawMutex};
    use embassy_sync::blocking_mutex::Mutex as Blocking;
    use embassy_sync::mutex::Mutex as AsyncMutex;
    use picoserve::Router;
    use remodaq_protocol::auth::KEY_LEN;
    use remodaq_protocol::update::{Header, Status, HEADER_LEN};
    use remodaq_protocol::web::{request_signature, HEADER_COUNTER, HEADER_SESSION, HEADER_SIGNATURE, SESSION_ID_LEN};
    use remodaq_shared::identity::Identity;
    use remodaq_shared::modbus::{Access, Exception, RegisterMap, Table, WriteValues};
    use remodaq_shared::module::SettingsAccess;
    use remodaq_shared::ram_flash::RamFlash;
    use remodaq_shared::settings::{Schema, SettingsStore};
    use remodaq_shared::upload::{WebDone, WebStep, WEB};
    use remodaq_web::service::{Api, SharedSessions, CONFIG, HTTP_BUFFER};
    use remodaq_web::Sessions;

    use super::common::S;
    use super::memory_connection::Connection;
    use super::{credential, log_in, turn, PAGE, PASSWORD};

    /// docs/web.md: "once the first has sent nothing for 30 s".
    const ABANDONED: u64 = 30_000;

    type Flash = RamFlash<8192, 1024>;

    /// The module's clock, as the test sets it.
    static NOW: AtomicU64 = AtomicU64::new(0);

    fn now() -> u64 {
        NOW.load(Ordering::SeqCst)
    }

    /// A module with no registers, and a password of its own (an upload is refused with the
    /// factory one).
    struct Map(S);

    impl RegisterMap for Map {
        fn access(&self, _: Table, _: u16) -> Access {
            Access::None
        }
        fn read(&mut self, _: Table, _: u16) -> u16 {
            0
        }
        fn validate(&self, _: u16, _: &WriteValues<'_>) -> Result<(), Exception> {
            Err(Exception::IllegalDataAddress)
        }
    }

    impl SettingsAccess for Map {
        type Settings = S;
        fn settings(&self) -> &S {
            &self.0
        }
        fn committed(&mut self, s: &S) {
            self.0 = *s;
        }
    }

    /// A page's session: its id, key and last counter.
    struct Page {
        id: [u8; SESSION_ID_LEN],
        key: [u8; KEY_LEN],
        counter: u64,
    }

    fn hex(bytes: &[u8]) -> String {
        bytes.iter().map(|b| format!("{b:02x}")).collect()
    }

    struct Module {
        map: AsyncMutex<NoopRawMutex, Map>,
        store: AsyncMutex<CriticalSectionRawMutex, SettingsStore<Flash, S>>,
        sessions: SharedSessions,
        /// The steps the update task was given.
        steps: RefCell<Vec<String>>,
    }

    impl Module {
        fn new() -> Self {
            let settings = S { password: credential(), ..S::defaults() };
            let store = embassy_futures::block_on(SettingsStore::open(
                Flash::new(),
                const { SettingsStore::<Flash, S>::config(0..8192) },
            ));
            Self {
                map: AsyncMutex::new(Map(settings)),
                store: AsyncMutex::new(store),
                sessions: Blocking::new(RefCell::new(Sessions::new())),
                steps: RefCell::new(Vec::new()),
            }
        }

        fn log_in(&self, at: u64) -> Page {
            NOW.store(at, Ordering::SeqCst);
            let credential = credential();
            let (id, key) = self
                .sessions
                .lock(|s| log_in(&mut s.borrow_mut(), &credential, PASSWORD, PAGE, at))
                .expect("the module's password logs in");
            Page { id, key, counter: 0 }
        }

        /// `method target` with `body`, signed by `page`, at `at` ms: the status and the body.
        fn signed(&self, at: u64, page: &mut Page, method: &str, target: &str, body: &[u8]) -> (u16, String) {
            page.counter += 1;
            let signature = request_signature(&page.key, method, target, page.counter, body);
            let mut request = format!(
                "{method} {target} HTTP/1.1\r\nHost: 192.168.0.1\r\nContent-Length: {}\r\n{HEADER_SESSION}: {}\r\n\
                 {HEADER_COUNTER}: {}\r\n{HEADER_SIGNATURE}: {}\r\n\r\n",
                body.len(),
                hex(&page.id),
                page.counter,
                hex(&signature)
            )
            .into_bytes();
            request.extend_from_slice(body);
            self.serve(at, &request)
        }

        /// Serves one connection carrying `request` at `at` ms, beside the update task.
        fn serve(&self, at: u64, request: &[u8]) -> (u16, String) {
            NOW.store(at, Ordering::SeqCst);
            let identity = Identity {
                model: 0x8350,
                version: 0xA100,
                name: "RemoDAQ-8350",
                mac: super::MAC,
                running: remodaq_protocol::net::NetConfig::FACTORY,
            };
            let restart = Cell::new(false);
            let api = Api {
                map: &self.map,
                store: &self.store,
                identity,
                sessions: &self.sessions,
                peer: PAGE,
                now_ms: now,
                restart: &restart,
            };
            let app = Router::from_service(api);
            let mut buffer = [0u8; HTTP_BUFFER];
            let mut output = Vec::new();
            let connection = Connection { input: request, output: &mut output, piece: usize::MAX };
            let served =
                picoserve::Server::custom(&app, picoserve::time::EmbassyTimer, &CONFIG, &mut buffer).serve(connection);
            // The update task: each step is carried out as for a good image.
            let task = async {
                loop {
                    let (number, step) = WEB.next().await;
                    let done = match step {
                        WebStep::Begin(header) => {
                            self.steps.borrow_mut().push("begin".into());
                            Header::decode(&header).map(WebDone::Begun).ok_or(Status::Invalid)
                        }
                        WebStep::Write { offset, len, .. } => {
                            self.steps.borrow_mut().push(format!("write {offset}"));
                            Ok(WebDone::Written(offset + len as u32))
                        }
                        WebStep::Finish => {
                            self.steps.borrow_mut().push("finish".into());
                            Ok(WebDone::NoUpload)
                        }
                    };
                    WEB.answer(number, done);
                }
            };
            // The task first: it waits for steps (`WEB.is_served`) before the request is read.
            match embassy_futures::block_on(select(task, served)) {
                Either::First(()) => unreachable!("the update task never ends"),
                Either::Second(result) => assert!(result.is_ok(), "the connection failed"),
            }
            let text = String::from_utf8(output).expect("an HTTP answer");
            let (head, body) = text.split_once("\r\n\r\n").expect("a head and a body");
            let status = head.strip_prefix("HTTP/1.1 ").and_then(|r| r.get(..3)).and_then(|c| c.parse().ok());
            (status.expect("a status line"), body.to_string())
        }

        fn steps(&self) -> Vec<String> {
            self.steps.borrow().clone()
        }
    }

    fn header() -> Vec<u8> {
        let header =
            Header { model: 0x8350, version: 0xA101, counter: 0, length: 3000, digest: [1; 64], signature: [2; 64] };
        let bytes = header.encode().to_vec();
        assert_eq!(bytes.len(), HEADER_LEN);
        bytes
    }

    #[test]
    fn a_second_session_waits_30_s_without_a_step_or_the_owners_logout() {
        let _turn = turn();
        let module = Module::new();
        let (mut a, mut b) = (module.log_in(1000), module.log_in(1000));
        let header = header();
        let begin = |at, page: &mut Page| module.signed(at, page, "POST", "/api/v1/firmware", &header);

        // A begins its upload.
        let (status, body) = begin(1500, &mut a);
        assert_eq!(status, 200, "{body}");
        // The owner may begin again (a page that starts over): the rule holds other sessions.
        let (status, body) = begin(2000, &mut a);
        assert_eq!(status, 200, "{body}");
        assert_eq!(module.steps(), ["begin"; 2]);
        // B may not, until A has sent nothing for 30 s: 409, and nothing reaches the update task.
        for at in [2001, 20_000, 2000 + ABANDONED - 1] {
            let (status, body) = begin(at, &mut b);
            assert_eq!(status, 409, "{at} ms: {body}");
            assert!(body.contains("under way"), "{body}");
        }
        assert_eq!(module.steps(), ["begin"; 2], "a refused begin never reaches the update task");
        // A sends a chunk, later than 30 s after its begin (nobody took its upload): the 30 s
        // start again from this step.
        let at = 2000 + ABANDONED + 1000;
        let (status, body) = module.signed(at, &mut a, "PUT", "/api/v1/firmware/0", &[0xAB; 512]);
        assert_eq!((status, body.as_str()), (200, r#"{"received":512}"#));
        let (status, body) = begin(at + ABANDONED - 1, &mut b);
        assert_eq!(status, 409, "29.999 s after A's last step: {body}");
        assert_eq!(module.steps(), ["begin", "begin", "write 0"]);
        // 30 s without a step: B takes over; A's upload is no longer A's.
        let (status, body) = begin(at + ABANDONED, &mut b);
        assert_eq!(status, 200, "30 s after A's last step: {body}");
        assert_eq!(module.steps(), ["begin", "begin", "write 0", "begin"]);
        let t = at + ABANDONED;
        let (status, body) = module.signed(t + 1, &mut a, "PUT", "/api/v1/firmware/512", &[0xAB; 512]);
        assert_eq!(status, 409, "{body}");
        assert!(body.contains("no upload of this session"), "{body}");
        assert_eq!(module.steps().len(), 4, "A's chunk never reaches the update task");

        // A logs out: B's upload stays B's (C, logged in since, waits).
        assert_eq!(module.signed(t + 2, &mut a, "DELETE", "/api/v1/session", b"").0, 204);
        let mut c = module.log_in(t + 3);
        assert_eq!(begin(t + 4, &mut c).0, 409, "A's logout releases nothing of B's");
        // B logs out: its upload is released, and C begins at once.
        assert_eq!(module.signed(t + 5, &mut b, "DELETE", "/api/v1/session", b"").0, 204);
        let (status, body) = begin(t + 6, &mut c);
        assert_eq!(status, 200, "B logged out 1 ms ago: {body}");
        assert_eq!(module.steps(), ["begin", "begin", "write 0", "begin", "begin"]);
    }
}
