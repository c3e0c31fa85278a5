//! The web console's sessions (docs/web.md, "Authentication"), with the page's side computed
//! as docs/web.md tells a page to: PBKDF2 for ClientKey (`auth::derive`, checked against RFC
//! 7677 in the protocol crate), the proof, the session key, the signature of each request.

use std::sync::Mutex;

use remodaq_protocol::auth::{client_proof, derive, server_signature, Credential, KEY_LEN, NONCE_LEN};
use remodaq_protocol::web::{login_message, request_signature, session_key, SESSION_ID_LEN};
use remodaq_shared::password::AUTH;
use remodaq_shared::web::{
    Login, LoginError, Refusal, Sessions, Signed, Verified, CHALLENGE_MS, IDLE_MS, MAX_AGE_MS, SESSIONS,
};

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
    // Too late.
    let nonce = sessions.challenge(&credential, PAGE, 0).expect("seeded").nonce;
    assert_eq!(sessions.login(&credential, &MAC, &login_for(nonce), PAGE, CHALLENGE_MS), Err(LoginError::Challenge));
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
    assert_eq!(sessions.live(1000), SESSIONS);
    // a is used, so b is now the one idle the longest: a third login ends b.
    assert_eq!(
        sessions.verify(&signed(a, &key_a, "POST", "/x", 1, b""), &credential, 2000),
        Ok(Verified { factory: false })
    );
    let (c, key_c) = log_in(&mut sessions, &credential, PASSWORD, PAGE, 3000).expect("login c");
    assert_eq!(sessions.live(3000), SESSIONS);
    assert_eq!(sessions.verify(&signed(b, &key_b, "POST", "/x", 1, b""), &credential, 3000), Err(Refusal::NoSession));
    // Idle for IDLE_MS: ended.
    assert_eq!(
        sessions.verify(&signed(c, &key_c, "POST", "/x", 1, b""), &credential, 3000 + IDLE_MS - 1),
        Ok(Verified { factory: false })
    );
    assert_eq!(
        sessions.verify(&signed(a, &key_a, "POST", "/x", 2, b""), &credential, 2000 + IDLE_MS),
        Err(Refusal::NoSession)
    );
    // Logged out.
    sessions.end(&c);
    assert_eq!(
        sessions.verify(&signed(c, &key_c, "POST", "/x", 2, b""), &credential, 3000 + IDLE_MS),
        Err(Refusal::NoSession)
    );
    assert_eq!(sessions.live(3000 + IDLE_MS), 0);
}

#[test]
fn a_new_password_ends_every_session_and_none_lives_past_8_hours() {
    let _turn = turn();
    let credential = credential();
    let mut sessions = Sessions::new();
    let (id, key) = log_in(&mut sessions, &credential, PASSWORD, PAGE, 0).expect("login");
    // Busy all along: still ended MAX_AGE_MS after the login.
    let mut counter = 0;
    let mut now = 0;
    while now + IDLE_MS / 2 < MAX_AGE_MS {
        now += IDLE_MS / 2;
        counter += 1;
        assert_eq!(
            sessions.verify(&signed(id, &key, "POST", "/x", counter, b""), &credential, now),
            Ok(Verified { factory: false })
        );
    }
    assert_eq!(
        sessions.verify(&signed(id, &key, "POST", "/x", counter + 1, b""), &credential, MAX_AGE_MS),
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
