//! The web console's API on the host build (`--http`, docs/web.md), as real HTTP requests over
//! loopback: logins, signed writes confirmed by Modbus reads, and the attacks of issue #25
//! (unsigned, stale, replayed, altered and cross-origin requests refused with nothing changed;
//! GET never changes state; oversized heads and bodies, and a slow client, leave it serving).

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use remodaq_board_host::testing::SimModule;
use remodaq_protocol::auth::{client_proof, derive, server_signature, FACTORY_PASSWORD, KEY_LEN, NONCE_LEN};
use remodaq_protocol::m8350::BIT_DO;
use remodaq_protocol::web::{hex, login_message, request_signature, session_key, unhex, SESSION_ID_LEN};
use tokio_modbus::client::{tcp, Reader};

const BIN: &str = env!("CARGO_BIN_EXE_firmware-8350");

fn temp(name: &str) -> PathBuf {
    remodaq_board_host::testing::temp("web-8350", name)
}

/// An HTTP answer: status, body.
struct Answer {
    status: u16,
    body: String,
}

/// Sends `request` (the whole text) and reads the answer until the module closes.
fn send_raw(web: SocketAddr, request: &[u8]) -> Answer {
    let mut s = TcpStream::connect(web).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let _ = s.write_all(request);
    let mut text = Vec::new();
    let _ = s.read_to_end(&mut text);
    let text = String::from_utf8_lossy(&text).into_owned();
    let status = text.split(' ').nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    let body = text.split_once("\r\n\r\n").map_or(String::new(), |(_, b)| b.to_string());
    Answer { status, body }
}

fn request(web: SocketAddr, method: &str, target: &str, headers: &[(&str, String)], body: &str) -> Answer {
    let mut text = format!("{method} {target} HTTP/1.1\r\nHost: {web}\r\nContent-Length: {}\r\n", body.len());
    for (name, value) in headers {
        text += &format!("{name}: {value}\r\n");
    }
    text += "\r\n";
    text += body;
    send_raw(web, text.as_bytes())
}

/// The value of `"field":"..."` in a JSON text.
fn field<'a>(json: &'a str, name: &str) -> &'a str {
    let key = format!("\"{name}\":\"");
    json.split(&key).nth(1).and_then(|rest| rest.split('"').next()).unwrap_or("")
}

/// A logged-in page: its session and key, and its next counter.
struct Page {
    session: [u8; SESSION_ID_LEN],
    key: [u8; KEY_LEN],
    counter: u64,
}

impl Page {
    /// The headers of a signed request.
    fn sign(&mut self, method: &str, target: &str, body: &str) -> Vec<(&'static str, String)> {
        self.counter += 1;
        let signature = request_signature(&self.key, method, target, self.counter, body.as_bytes());
        let (mut id, mut sig) = ([0u8; 16], [0u8; 64]);
        vec![
            ("X-RDAQ-Session", hex(&self.session, &mut id).unwrap_or("").to_string()),
            ("X-RDAQ-Counter", self.counter.to_string()),
            ("X-RDAQ-Signature", hex(&signature, &mut sig).unwrap_or("").to_string()),
        ]
    }
}

/// Logs in as a page does (docs/web.md); the answer when it fails.
fn log_in(web: SocketAddr, password: &str) -> Result<Page, Answer> {
    let challenge = request(web, "POST", "/api/v1/session/challenge", &[], "");
    assert_eq!(challenge.status, 200, "{}", challenge.body);
    let salt: [u8; 16] = unhex(field(&challenge.body, "salt")).expect("salt");
    let nonce: [u8; NONCE_LEN] = unhex(field(&challenge.body, "nonce")).expect("nonce");
    let iterations: u32 = challenge
        .body
        .split("\"iterations\":")
        .nth(1)
        .and_then(|r| r.split(',').next())
        .and_then(|n| n.parse().ok())
        .expect("iterations");
    let identity = request(web, "GET", "/api/v1/identity", &[], "");
    let mac: [u8; 6] = unhex(field(&identity.body, "mac")).expect("mac");
    let page_nonce = [0x42; NONCE_LEN];
    let (client_key, credential) = derive(password.as_bytes(), &salt, iterations);
    let message = login_message(&mac, &nonce, &page_nonce);
    let proof = client_proof(&client_key, &message);
    let (mut n, mut pn, mut p) = ([0u8; 32], [0u8; 32], [0u8; 64]);
    let body = format!(
        "{{\"nonce\":\"{}\",\"page_nonce\":\"{}\",\"proof\":\"{}\"}}",
        hex(&nonce, &mut n).unwrap_or(""),
        hex(&page_nonce, &mut pn).unwrap_or(""),
        hex(&proof, &mut p).unwrap_or("")
    );
    let answer = request(web, "POST", "/api/v1/session", &[], &body);
    if answer.status != 200 {
        return Err(answer);
    }
    let session: [u8; SESSION_ID_LEN] = unhex(field(&answer.body, "session")).expect("session id");
    let signature: [u8; KEY_LEN] = unhex(field(&answer.body, "signature")).expect("signature");
    assert_eq!(
        signature,
        server_signature(&credential.server_key, &[message[0], message[1], message[2], message[3], &session]),
        "the module signed its answer with this password's ServerKey"
    );
    Ok(Page { session, key: session_key(&client_key, &nonce, &page_nonce), counter: 0 })
}

async fn coils(modbus: SocketAddr) -> Vec<bool> {
    let mut ctx = tcp::connect(modbus).await.expect("modbus");
    ctx.read_coils(BIT_DO, 6).await.unwrap().expect("no exception")
}

async fn auth_failures(modbus: SocketAddr) -> u16 {
    let mut ctx = tcp::connect(modbus).await.expect("modbus");
    ctx.read_holding_registers(0xF9, 1).await.unwrap().expect("no exception")[0]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn logins_signed_writes_and_the_attacks() {
    let module = SimModule::start_with(BIN, &temp("web.flash"), &["--listen", "127.0.0.1:0", "--http", "127.0.0.1:0"]);
    let (web, modbus) = (module.web.expect("web address"), module.addr);

    // Identity, read without a login.
    let identity = request(web, "GET", "/api/v1/identity", &[], "");
    assert_eq!(identity.status, 200);
    assert_eq!(field(&identity.body, "model"), "8350");

    // A wrong password: 401, counted as an authentication failure (diagnostics 00F9h).
    let failures = auth_failures(modbus).await;
    let wrong = log_in(web, "not the password").err().expect("a wrong password is refused");
    assert_eq!((wrong.status, field(&wrong.body, "error")), (401, "wrong password"));
    assert_eq!(auth_failures(modbus).await, failures + 1);

    // The right one (the factory password of a fresh module), then DO1 on, signed: Modbus
    // confirms.
    let mut page = log_in(web, FACTORY_PASSWORD).unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    let target = format!("/api/v1/coils/{}", BIT_DO + 1);
    let body = r#"{"value":true}"#;
    let headers = page.sign("PUT", &target, body);
    let on = request(web, "PUT", &target, &headers, body);
    assert_eq!(on.status, 204, "{}", on.body);
    assert_eq!(coils(modbus).await, [false, true, false, false, false, false]);
    // GET reads it, through the same register map.
    let read = request(web, "GET", &format!("/api/v1/coils/{BIT_DO}?count=6"), &[], "");
    assert_eq!(read.body, r#"{"values":[false,true,false,false,false,false]}"#);

    // The attacks: each refused, DO1 still on, DO0 still off.
    let off = r#"{"value":false}"#;
    let expect_refused = |answer: Answer, what: &str, status: u16| {
        assert_eq!((answer.status, field(&answer.body, "error")), (status, what), "{}", answer.body);
    };
    // Unsigned.
    expect_refused(request(web, "PUT", &target, &[], off), "unsigned", 401);
    // Replayed: the exact request recorded above.
    expect_refused(request(web, "PUT", &target, &headers, body), "stale counter", 401);
    // Stale: signed right by the key, but with a counter already used.
    page.counter = 0;
    let stale = page.sign("PUT", &target, off);
    expect_refused(request(web, "PUT", &target, &stale, off), "stale counter", 401);
    page.counter = 10;
    // Altered: signed for DO1 off, sent with another body, or to another DO.
    let signed = page.sign("PUT", &target, off);
    expect_refused(request(web, "PUT", &target, &signed, r#"{"value":true }"#), "bad signature", 401);
    let other = format!("/api/v1/coils/{BIT_DO}");
    expect_refused(request(web, "PUT", &other, &signed, off), "bad signature", 401);
    // From another origin's page (a forged form or fetch that carried the headers): 403.
    let mut foreign = page.sign("PUT", &target, off);
    foreign.push(("Origin", "http://attacker.example".to_string()));
    expect_refused(request(web, "PUT", &target, &foreign, off), "request from another origin", 403);
    assert_eq!(coils(modbus).await, [false, true, false, false, false, false], "nothing changed");

    // GET never changes state: every resource read with the attacker's writes as queries.
    for target in ["/api/v1/identity", "/api/v1/coils/16?count=6", "/api/v1/registers/0?count=10", "/api/v1/session"] {
        let _ = request(web, "GET", &format!("{target}&value=false"), &page.sign("GET", target, off), off);
        let _ = request(web, "GET", target, &page.sign("GET", target, off), off);
    }
    assert_eq!(coils(modbus).await, [false, true, false, false, false, false], "GET changed nothing");

    // A value the module refuses (register 0 is read-only): a 4xx naming the field.
    let bad = r#"{"value":1}"#;
    let headers = page.sign("PUT", "/api/v1/registers/0", bad);
    let refused = request(web, "PUT", "/api/v1/registers/0", &headers, bad);
    assert!((400..500).contains(&refused.status), "{} {}", refused.status, refused.body);

    // Oversized head and body: refused, and the module goes on serving.
    let huge_header = format!("GET /api/v1/identity HTTP/1.1\r\nX-Junk: {}\r\n\r\n", "x".repeat(8000));
    let answer = send_raw(web, huge_header.as_bytes());
    assert!(answer.status == 0 || (400..500).contains(&answer.status), "oversized head: {}", answer.status);
    let huge_body = "y".repeat(64 * 1024);
    let answer = request(web, "PUT", &target, &[], &huge_body);
    assert!(answer.status == 0 || answer.status == 413, "oversized body: {}", answer.status);
    // A slow client holds one connection; the other still answers, and Modbus too.
    let mut slow = TcpStream::connect(web).expect("connect");
    let _ = slow.write_all(b"GET /api/v1/ident");
    let started = Instant::now();
    assert_eq!(request(web, "GET", "/api/v1/identity", &[], "").status, 200);
    assert!(started.elapsed() < Duration::from_secs(2), "served beside a slow client");
    assert_eq!(coils(modbus).await, [false, true, false, false, false, false]);

    // Logged out: the session's next signed request is refused.
    let headers = page.sign("DELETE", "/api/v1/session", "");
    assert_eq!(request(web, "DELETE", "/api/v1/session", &headers, "").status, 204);
    let headers = page.sign("PUT", &target, off);
    expect_refused(request(web, "PUT", &target, &headers, off), "no session", 401);
    drop(slow);
}
