//! The web console's API on the host build (`--http`, docs/web.md), as real HTTP requests over
//! loopback: logins, signed writes confirmed by Modbus reads, and the attacks of issue #25
//! (unsigned, stale, replayed, altered, cross-origin and DNS-rebound requests refused with
//! nothing changed; GET never changes state; oversized heads and bodies, and a slow client,
//! leave it serving).

use std::io::Write;
use std::net::{SocketAddr, TcpStream};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use remodaq_board_host::testing::web::{field, log_in, number, request, request_to_host, send_raw, Answer};
use remodaq_board_host::testing::SimModule;
use remodaq_protocol::auth::FACTORY_PASSWORD;
use remodaq_protocol::m8350::BIT_DO;
use remodaq_protocol::update::HEADER_LEN;
use tokio_modbus::client::{tcp, Reader, Writer as _};

const BIN: &str = env!("CARGO_BIN_EXE_firmware-8350");

fn temp(name: &str) -> PathBuf {
    remodaq_board_host::testing::temp("web-8350", name)
}

async fn coils(modbus: SocketAddr) -> Vec<bool> {
    let mut ctx = tcp::connect(modbus).await.expect("modbus");
    ctx.read_coils(BIT_DO, 6).await.unwrap().expect("no exception")
}

async fn auth_failures(modbus: SocketAddr) -> u16 {
    let mut ctx = tcp::connect(modbus).await.expect("modbus");
    ctx.read_holding_registers(0xF9, 1).await.unwrap().expect("no exception")[0]
}

/// Asserts that `answer` is a refusal with this status and reason.
fn expect_refused(answer: Answer, what: &str, status: u16) {
    assert_eq!((answer.status, field(&answer.body, "error")), (status, what), "{}", answer.body);
}

/// Every answer's headers as docs/web.md ("The server") lists them: a page's file compressed
/// and checked again at each load, a JSON answer never stored, and on both what stops another
/// site from framing the page, loading other scripts or sniffing types.
#[test]
fn pages_and_json_answers_carry_their_headers() {
    let module =
        SimModule::start_with(BIN, &temp("headers.flash"), &["--listen", "127.0.0.1:0", "--http", "127.0.0.1:0"]);
    let web = module.web.expect("web address");
    let security = [
        ("Content-Security-Policy", "default-src 'self'; frame-ancestors 'none'; form-action 'self'"),
        ("X-Content-Type-Options", "nosniff"),
        ("Referrer-Policy", "no-referrer"),
    ];
    let page = request(web, "GET", "/app.js", &[], "");
    let json = request(web, "GET", "/api/v1/identity", &[], "");
    let rebound = request_to_host(web, "attacker.example", "GET", "/api/v1/identity", &[], "");
    assert_eq!((page.status, json.status, rebound.status), (200, 200, 421));
    let page_headers = [
        ("Content-Type", "text/javascript; charset=utf-8"),
        ("Content-Encoding", "gzip"),
        ("Cache-Control", "no-cache"),
    ];
    for (name, value) in page_headers.into_iter().chain(security) {
        assert_eq!(page.header(name), Some(value), "/app.js {name}:\n{}", page.head);
    }
    for answer in [&json, &rebound] {
        for (name, value) in
            [("Content-Type", "application/json"), ("Cache-Control", "no-store")].into_iter().chain(security)
        {
            assert_eq!(answer.header(name), Some(value), "{name}:\n{}", answer.head);
        }
        assert_eq!(answer.header("Content-Encoding"), None, "{}", answer.head);
    }
}

/// What a GET could change, as Modbus shows it without clearing anything (spec §3.1, §3.2,
/// extensions §3): the DOs, the counters' run bits, the DI and DO modes, the pulse settings,
/// all DO, and the host watchdog's registers.
async fn settings_and_outputs(modbus: SocketAddr) -> Vec<Vec<u16>> {
    let mut ctx = tcp::connect(modbus).await.expect("modbus");
    let mut seen = Vec::new();
    let bits = ctx.read_coils(BIT_DO, 6).await.unwrap().expect("no exception");
    seen.push(bits.iter().map(|&b| u16::from(b)).collect());
    let mut run = Vec::new();
    for n in 0..12 {
        run.push(u16::from(ctx.read_coils(0x20 + 4 * n, 1).await.unwrap().expect("no exception")[0]));
    }
    seen.push(run);
    for (addr, n) in [(0x18, 48), (0x100, 12), (0x110, 6), (0x12E, 1), (0x130, 5)] {
        seen.push(ctx.read_holding_registers(addr, n).await.unwrap().expect("no exception"));
    }
    seen
}

/// What the web shows of the DIs (states, modes, counters, flags), the DOs and the watchdog:
/// read as a GET reads, so reading it changes nothing.
fn shown(web: SocketAddr) -> Vec<String> {
    ["/api/v1/di", "/api/v1/do", "/api/v1/watchdog"].map(|t| request(web, "GET", t, &[], "").body).to_vec()
}

/// docs/web.md, "Decisions": "the API sends no CORS headers". Another site's page may send
/// requests to the module (a browser lets it), but without an `Access-Control-Allow-*` header
/// the browser shows it none of the answers and sends no preflighted request (a signed write's
/// headers need one). No answer carries an `Access-Control-*` header: pages, JSON, errors, the
/// answers to OPTIONS (a preflight) and to requests from another origin.
#[test]
fn no_answer_carries_a_cors_header() {
    let module = SimModule::start_with(BIN, &temp("cors.flash"), &["--listen", "127.0.0.1:0", "--http", "127.0.0.1:0"]);
    let web = module.web.expect("web address");
    let foreign = || ("Origin", "http://attacker.example".to_string());
    let preflight = || {
        vec![
            foreign(),
            ("Access-Control-Request-Method", "PUT".to_string()),
            ("Access-Control-Request-Headers", "content-type,x-rdaq-session,x-rdaq-counter,x-rdaq-signature".into()),
        ]
    };
    let mut page = log_in(web, FACTORY_PASSWORD).unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    let off = r#"{"value":false}"#;
    let mut signed_foreign = page.sign("PUT", "/api/v1/do/0/state", off);
    signed_foreign.push(foreign());
    let answers = [
        ("page", request(web, "GET", "/", &[], "")),
        ("script", request(web, "GET", "/app.js", &[], "")),
        ("read", request(web, "GET", "/api/v1/do", &[], "")),
        ("foreign read", request(web, "GET", "/api/v1/do", &[foreign()], "")),
        ("foreign page", request(web, "GET", "/", &[foreign()], "")),
        ("foreign challenge", request(web, "POST", "/api/v1/session/challenge", &[foreign()], "")),
        ("foreign signed write", request(web, "PUT", "/api/v1/do/0/state", &signed_foreign, off)),
        ("foreign unsigned write", request(web, "PUT", "/api/v1/do/0/state", &[foreign()], off)),
        ("preflight of a write", request(web, "OPTIONS", "/api/v1/do/0/state", &preflight(), "")),
        ("preflight of a login", request(web, "OPTIONS", "/api/v1/session", &preflight(), "")),
        ("preflight of the page", request(web, "OPTIONS", "/", &preflight(), "")),
        (
            "OPTIONS *",
            send_raw(
                web,
                format!("OPTIONS * HTTP/1.1\r\nHost: {web}\r\nOrigin: http://attacker.example\r\n\r\n").as_bytes(),
            ),
        ),
        ("rebound", request_to_host(web, "attacker.example", "GET", "/api/v1/do", &[foreign()], "")),
        ("no such resource", request(web, "GET", "/api/v1/nothing", &[foreign()], "")),
    ];
    for (what, answer) in &answers {
        assert_ne!(answer.status, 0, "{what}: no answer");
        let cors: Vec<_> =
            answer.head.lines().filter(|l| l.to_ascii_lowercase().starts_with("access-control-")).collect();
        assert!(cors.is_empty(), "{what} ({}): {cors:?}", answer.status);
    }
    // A preflight never succeeds: the API has no OPTIONS operation (docs/openapi.yaml).
    for (what, answer) in answers.iter().filter(|(what, _)| what.starts_with("preflight")) {
        assert!(!(200..300).contains(&answer.status), "{what}: {} {}", answer.status, answer.head);
    }
    // The refusals docs/web.md gives: another origin's state change 403, a rebound Host 421.
    let status = |what: &str| answers.iter().find(|(w, _)| *w == what).map(|(_, a)| a.status);
    assert_eq!(status("foreign signed write"), Some(403));
    assert_eq!(status("rebound"), Some(421));
    assert_eq!(status("foreign read"), Some(200), "reading needs no login, from anywhere (docs/web.md)");
}

/// docs/web.md, "Decisions": "a web read does not feed the host watchdog (a browser left open
/// must not keep a dead master's outputs alive)". The master arms a 0.5 s watchdog fed by any
/// request (extensions §3: 0130h = 5, 0132h = 0) and goes silent; a browser polls
/// `GET /api/v1/do` every 100 ms: the watchdog trips 500-600 ms after the arming write, as
/// with nobody polling, and the DOs take their safe levels.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_web_read_never_feeds_the_host_watchdog() {
    let module =
        SimModule::start_with(BIN, &temp("wd-web.flash"), &["--listen", "127.0.0.1:0", "--http", "127.0.0.1:0"]);
    let (web, modbus) = (module.web.expect("web address"), module.addr);
    let states =
        |body: &str| -> Vec<bool> { body.split("\"state\":").skip(1).map(|r| r.starts_with("true")).collect() };
    let mut master = tcp::connect(modbus).await.expect("modbus");
    // DO1 on; safe levels (0131h): only DO2 on; mode 0 (0132h): any request feeds it.
    master.write_single_coil(BIT_DO + 1, true).await.unwrap().expect("DO1 on");
    master.write_single_register(0x131, 0b00_0100).await.unwrap().expect("safe values");
    master.write_single_register(0x132, 0).await.unwrap().expect("mode 0");
    let armed = Instant::now();
    master.write_single_register(0x130, 5).await.unwrap().expect("0.5 s");
    let answered = armed.elapsed();
    drop(master);
    let on = [false, true, false, false, false, false];
    let safe = [false, false, true, false, false, false];
    // The browser polls every 100 ms; the outputs change when the watchdog trips.
    let mut last_ok = Duration::ZERO;
    let tripped = loop {
        let sent = armed.elapsed();
        let answer = request(web, "GET", "/api/v1/do", &[], "");
        assert_eq!(answer.status, 200, "{}", answer.body);
        let now = states(&answer.body);
        if now == safe {
            break armed.elapsed();
        }
        assert_eq!(now, on, "{}", answer.body);
        last_ok = sent;
        assert!(armed.elapsed() < Duration::from_secs(3), "the web reads kept the host watchdog fed");
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    // Extensions §3: it trips when no feeding request arrived for the timeout (within +100
    // ms). The arming write took effect between its sending and its answer (`answered`); the
    // trip lies between the last poll that saw the outputs on (sent `last_ok` after the
    // arming) and the answer that saw them safe (`tripped`): that window must meet 500-600 ms.
    let earliest = last_ok.saturating_sub(answered);
    eprintln!("with the page polling, the watchdog tripped between {earliest:?} and {tripped:?} after arming");
    assert!(tripped >= Duration::from_millis(500), "tripped before 0.5 s without a Modbus request: {tripped:?}");
    assert!(earliest <= Duration::from_millis(600), "not tripped 0.6 s after the master's last request: {earliest:?}");
    let watchdog = request(web, "GET", "/api/v1/watchdog", &[], "");
    assert!(watchdog.body.contains("\"tripped\":1"), "{}", watchdog.body);
    assert_eq!(coils(modbus).await, safe, "Modbus shows the safe levels");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn logins_signed_writes_and_the_attacks() {
    let scenario = temp("attacks.toml");
    std::fs::write(&scenario, "[di2]\nlevel = false\n").unwrap();
    let args = ["--listen", "127.0.0.1:0", "--http", "127.0.0.1:0", "--scenario", scenario.to_str().unwrap()];
    let module = SimModule::start_with(BIN, &temp("web.flash"), &args);
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
    // DNS rebinding: a hostile page under a name the attacker's DNS turned into the module's
    // address is same-origin to the browser (its Origin and Host both name it): 421, for a
    // write and for a read.
    let rebound = "attacker.example";
    let mut headers = page.sign("PUT", &target, off);
    headers.push(("Origin", format!("http://{rebound}")));
    let moved = "reach the module by its address";
    expect_refused(request_to_host(web, rebound, "PUT", &target, &headers, off), moved, 421);
    expect_refused(request_to_host(web, rebound, "GET", "/api/v1/do", &[], ""), moved, 421);
    assert_eq!(coils(modbus).await, [false, true, false, false, false, false], "nothing changed");

    // GET never changes state. Flags a Modbus read clears (spec §3.1) set first: DI2 as a
    // low-to-high latch (100h + 2 = 2), then its rising edge; DI0 counting (mode 1, run bit 20h).
    let mut ctx = tcp::connect(modbus).await.expect("modbus");
    ctx.write_single_register(0x102, 2).await.unwrap().expect("DI2 latch mode");
    ctx.write_single_register(0x100, 1).await.unwrap().expect("DI0 counter mode");
    ctx.write_single_coil(0x20, true).await.unwrap().expect("DI0 counter runs");
    drop(ctx);
    std::fs::write(&scenario, "[di2]\nlevel = true\n").unwrap();
    let started = Instant::now();
    while !request(web, "GET", "/api/v1/di/2", &[], "").body.contains("\"latch\":true") {
        assert!(started.elapsed() < Duration::from_secs(10), "the latch was never set");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let (before, shown_before) = (settings_and_outputs(modbus).await, shown(web));
    // Every resource, field and table read, each with the attacker's writes (signed, in the
    // body, and as a query: `?value=` on a target without one, `&value=` on one with).
    let targets = [
        "/api/v1/identity",
        "/api/v1/coils/16",
        "/api/v1/coils/16?count=6",
        "/api/v1/coils/43",
        "/api/v1/registers/0?count=10",
        "/api/v1/registers/304?count=5",
        "/api/v1/session",
        "/api/v1/session/challenge",
        "/api/v1/do",
        "/api/v1/do/1",
        "/api/v1/do/1/state",
        "/api/v1/do/0/state",
        "/api/v1/do/1/mode",
        "/api/v1/di",
        "/api/v1/di/0",
        "/api/v1/di/2/latch",
        "/api/v1/di/0/clear",
        "/api/v1/di/0/counting",
        "/api/v1/watchdog",
        "/api/v1/watchdog/timeout",
        "/api/v1/watchdog/tripped",
        "/api/v1/diagnostics",
        "/api/v1/network",
        "/api/v1/access",
        "/api/v1/password",
        "/api/v1/password/key",
        "/api/v1/restart",
        "/api/v1/firmware",
        "/api/v1/firmware/0",
        "/api/v1/firmware/finish",
    ];
    let mut statuses = Vec::new();
    for target in targets {
        for value in ["false", "true"] {
            let body = format!(r#"{{"value":{value}}}"#);
            let query = format!("{target}{}value={value}", if target.contains('?') { '&' } else { '?' });
            for sent in [target, query.as_str()] {
                let answer = request(web, "GET", sent, &page.sign("GET", sent, &body), &body);
                statuses.push((sent.to_string(), answer.status));
            }
        }
    }
    // The reads were served (not all refused before reaching the resources).
    for target in ["/api/v1/coils/43", "/api/v1/di/0", "/api/v1/do/1", "/api/v1/watchdog", "/api/v1/access"] {
        assert!(statuses.contains(&(target.to_string(), 200)), "{target}: {statuses:?}");
    }
    assert_eq!(settings_and_outputs(modbus).await, before, "GET changed a setting or an output");
    assert_eq!(shown(web), shown_before, "GET changed what the module shows");
    assert!(shown_before[0].contains("\"latch\":true"), "{}", shown_before[0]);
    // The latch is still set for the master: Modbus reads it set, once (a Modbus read clears it).
    let mut ctx = tcp::connect(modbus).await.expect("modbus");
    assert_eq!(ctx.read_coils(0x2B, 1).await.unwrap().unwrap(), [true], "a GET cleared DI2's latch");
    assert_eq!(ctx.read_coils(0x2B, 1).await.unwrap().unwrap(), [false]);
    drop(ctx);
    assert_eq!(coils(modbus).await, [false, true, false, false, false, false], "GET changed nothing");

    // A write of a read-only register (40001, a counter: spec §3.2): Modbus answers exception
    // 02 (illegal address), which the API answers 404 (docs/openapi.yaml lists 404 for this
    // write; 422 is for a value the map refuses, exception 03: docs/web.md, "One field per
    // write"). Nothing changed.
    let bad = r#"{"value":1}"#;
    let headers = page.sign("PUT", "/api/v1/registers/0", bad);
    let refused = request(web, "PUT", "/api/v1/registers/0", &headers, bad);
    assert_eq!(refused.status, 404, "{}", refused.body);
    assert_eq!(request(web, "GET", "/api/v1/registers/0", &[], "").body, r#"{"values":[0]}"#);

    // Oversized head and body: refused as docs/web.md says ("a head too large: 431/400 and the
    // connection closed; a body too large: 413"), and the module goes on serving.
    let huge_header = format!("GET /api/v1/identity HTTP/1.1\r\nX-Junk: {}\r\n\r\n", "x".repeat(8000));
    let answer = send_raw(web, huge_header.as_bytes());
    assert!(matches!(answer.status, 431 | 400), "oversized head: {} {}", answer.status, answer.body);
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

/// The named resources (docs/openapi.yaml) read and written through the register map: each
/// write confirmed by a Modbus read at the spec's address, a refused value named, and reads that
/// leave the flags Modbus clears by reading (spec §3.1) as they are.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn named_resources_agree_with_modbus() {
    let scenario = temp("resources.toml");
    std::fs::write(&scenario, "[di2]\nlevel = false\n").unwrap();
    let args = ["--listen", "127.0.0.1:0", "--http", "127.0.0.1:0", "--scenario", scenario.to_str().unwrap()];
    let module = SimModule::start_with(BIN, &temp("resources.flash"), &args);
    let (web, modbus) = (module.web.expect("web address"), module.addr);
    let mut ctx = tcp::connect(modbus).await.expect("modbus");
    let mut page = log_in(web, FACTORY_PASSWORD).unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    let mut put = |target: &str, body: &str| {
        let headers = page.sign("PUT", target, body);
        request(web, "PUT", target, &headers, body)
    };

    // Every DI and DO is listed, with the fields of the spec (modes by name).
    let di = request(web, "GET", "/api/v1/di", &[], "");
    assert_eq!(di.status, 200, "{}", di.body);
    assert_eq!(di.body.matches("\"state\":").count(), 12, "{}", di.body);
    assert!(
        di.body.starts_with(r#"{"di":[{"state":false,"mode":"normal","counter":0,"frequency":null,"#),
        "{}",
        di.body
    );
    let dos = request(web, "GET", "/api/v1/do", &[], "");
    assert_eq!(dos.body.matches("\"mode\":\"normal\"").count(), 6, "{}", dos.body);

    // DO3 to pulse mode with a high width of 70000 (0.1 ms): registers 40276, and 40041-40042
    // low word first (spec §3.2).
    assert_eq!(put("/api/v1/do/3/mode", r#"{"value":"pulse"}"#).status, 204);
    assert_eq!(put("/api/v1/do/3/high_width", r#"{"value":70000}"#).status, 204);
    assert_eq!(ctx.read_holding_registers(0x113, 1).await.unwrap().unwrap(), [1]);
    assert_eq!(ctx.read_holding_registers(0x2A, 2).await.unwrap().unwrap(), [(70000 - 65536) as u16, 1]);
    let do3 = request(web, "GET", "/api/v1/do/3", &[], "");
    assert_eq!((field(&do3.body, "mode"), number(&do3.body, "high_width")), ("pulse", Some(70000.0)), "{}", do3.body);

    // Refused values name their field, and change nothing: a mode that does not exist, a
    // watchdog timeout over 6000 (0.1 s, extensions §3: exception 03), a read-only counter.
    let refused = put("/api/v1/di/0/mode", r#"{"value":"sideways"}"#);
    assert_eq!((refused.status, field(&refused.body, "field")), (422, "mode"), "{}", refused.body);
    let refused = put("/api/v1/watchdog/timeout", r#"{"value":6001}"#);
    assert_eq!((refused.status, field(&refused.body, "field")), (422, "timeout"), "{}", refused.body);
    assert_eq!(ctx.read_holding_registers(0x130, 1).await.unwrap().unwrap(), [0]);
    let refused = put("/api/v1/di/0/counter", r#"{"value":5}"#);
    assert_eq!((refused.status, field(&refused.body, "field")), (405, "counter"), "{}", refused.body);
    assert_eq!(request(web, "GET", "/api/v1/di/12", &[], "").status, 404);
    // Unsigned: refused before anything is looked at.
    let unsigned = request(web, "PUT", "/api/v1/do/3/mode", &[], r#"{"value":"normal"}"#);
    assert_eq!((unsigned.status, field(&unsigned.body, "error")), (401, "unsigned"));
    assert_eq!(ctx.read_holding_registers(0x113, 1).await.unwrap().unwrap(), [1]);

    // DI2 as a low-to-high latch, then a rising edge (the scenario changes): the latch shows
    // in every GET, which does not clear it; the Modbus read (bit 0x2B) does (spec §3.1).
    assert_eq!(put("/api/v1/di/2/mode", r#"{"value":"latch rising"}"#).status, 204);
    std::fs::write(&scenario, "[di2]\nlevel = true\n").unwrap();
    let started = Instant::now();
    while !request(web, "GET", "/api/v1/di/2", &[], "").body.contains("\"latch\":true") {
        assert!(started.elapsed() < Duration::from_secs(10), "the latch was never set");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let again = request(web, "GET", "/api/v1/di/2", &[], "");
    assert!(again.body.contains("\"state\":true") && again.body.contains("\"latch\":true"), "{}", again.body);
    assert_eq!(ctx.read_coils(0x2B, 1).await.unwrap().unwrap(), [true]);
    assert_eq!(ctx.read_coils(0x2B, 1).await.unwrap().unwrap(), [false]);
    assert!(request(web, "GET", "/api/v1/di/2", &[], "").body.contains("\"latch\":false"));

    // Diagnostics, with the 8350's output timing.
    let diag = request(web, "GET", "/api/v1/diagnostics", &[], "");
    assert!(number(&diag.body, "uptime_s").is_some() && diag.body.contains("\"pattern_underruns\":"), "{}", diag.body);
}

/// Issue #25: 50 parallel connections leave the module serving. First 50 complete requests at
/// once, each answered; then 50 connections that send half a request and hold it (slowloris
/// from many sockets): Modbus answers all the while, and the console answers again once they
/// are gone (closed by the client, or by the module's timeouts).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fifty_parallel_connections_leave_it_serving() {
    let module =
        SimModule::start_with(BIN, &temp("fifty.flash"), &["--listen", "127.0.0.1:0", "--http", "127.0.0.1:0"]);
    let (web, modbus) = (module.web.expect("web address"), module.addr);

    let answers: Vec<u16> = std::thread::scope(|s| {
        let clients: Vec<_> =
            (0..50).map(|_| s.spawn(move || request(web, "GET", "/api/v1/identity", &[], "").status)).collect();
        clients.into_iter().map(|c| c.join().expect("client")).collect()
    });
    assert_eq!(answers, vec![200; 50], "each of 50 parallel requests answered");

    let mut held = Vec::new();
    for _ in 0..50 {
        let mut s = TcpStream::connect(web).expect("connect");
        let _ = s.write_all(b"GET /api/v1/identity HTTP/1.1\r\nHost: ");
        held.push(s);
    }
    for _ in 0..10 {
        assert_eq!(coils(modbus).await.len(), 6, "Modbus answers beside 50 held web connections");
    }
    drop(held);
    // The console is back once the held connections are gone: within their timeouts at most
    // (docs/web.md: 10 s a connection, two served at a time).
    let back = Instant::now();
    let status = loop {
        let status = request(web, "GET", "/api/v1/identity", &[], "").status;
        if status == 200 || back.elapsed() > Duration::from_secs(60) {
            break status;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    assert_eq!(status, 200, "the console answers after 50 held connections");
}

/// The network settings and the Modbus write allow-list over the API (docs/openapi.yaml): a
/// change needs a signed request; a bad value is refused naming its field with nothing stored;
/// a good one is stored, as discovery's search and Modbus then show; a signed restart puts the
/// stored settings in force.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn network_settings_allow_list_and_restart() {
    use remodaq_board_host::testing::search;
    use remodaq_protocol::discovery::{decode_info, info_flags};
    use remodaq_protocol::net::NetConfig;

    // A fixed web port, so that the console is at the same address after the restart.
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let http = format!("127.0.0.1:{port}");
    let mut module = SimModule::start_with(BIN, &temp("settings.flash"), &["--listen", "127.0.0.1:0", "--http", &http]);
    let web = module.web.expect("web address");
    let stored_at = |discovery| decode_info(&search(discovery)).map(|i| (i.stored, i.flags)).expect("INFO");
    let discovery = module.discovery;
    let stored = || stored_at(discovery);
    let (factory, flags) = stored();
    assert_eq!(factory, NetConfig::FACTORY, "a fresh module");
    assert_eq!(flags & info_flags::WRITES_RESTRICTED, 0);

    let shown = request(web, "GET", "/api/v1/network", &[], "");
    assert_eq!(shown.status, 200);
    assert!(
        shown
            .body
            .contains(r#""stored":{"ip":"192.168.0.1","mask":"255.255.255.0","gateway":"0.0.0.0","modbus_port":8000,"http_port":80}"#),
        "{}",
        shown.body
    );
    assert!(shown.body.contains(r#""restart_needed":false"#), "{}", shown.body);

    let new = r#"{"ip":"192.0.2.10","mask":"255.255.255.0","gateway":"192.0.2.1","modbus_port":8000,"http_port":8080}"#;
    // Unsigned: refused, nothing stored. The allow-list is not shown without a session.
    expect_refused(request(web, "PUT", "/api/v1/network", &[], new), "unsigned", 401);
    assert_eq!(request(web, "GET", "/api/v1/access", &[], "").status, 401);
    assert_eq!(request(web, "POST", "/api/v1/restart", &[], "").status, 401);
    assert_eq!(stored().0, NetConfig::FACTORY);

    let mut page = log_in(web, FACTORY_PASSWORD).unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    // A mask that is not contiguous: 422 naming it, nothing stored.
    let bad = r#"{"ip":"192.0.2.10","mask":"255.0.255.0","gateway":"192.0.2.1","modbus_port":8000,"http_port":8080}"#;
    let refused = request(web, "PUT", "/api/v1/network", &page.sign("PUT", "/api/v1/network", bad), bad);
    assert_eq!((refused.status, field(&refused.body, "field")), (422, "mask"), "{}", refused.body);
    assert_eq!(stored().0, NetConfig::FACTORY);
    // The console's port on Modbus's: 422 naming it.
    let clash =
        r#"{"ip":"192.0.2.10","mask":"255.255.255.0","gateway":"192.0.2.1","modbus_port":8000,"http_port":8000}"#;
    let refused = request(web, "PUT", "/api/v1/network", &page.sign("PUT", "/api/v1/network", clash), clash);
    assert_eq!((refused.status, field(&refused.body, "field")), (422, "http_port"), "{}", refused.body);
    // A usable one: stored (discovery shows it), in force after a restart.
    let changed = request(web, "PUT", "/api/v1/network", &page.sign("PUT", "/api/v1/network", new), new);
    assert_eq!(changed.status, 204, "{}", changed.body);
    let expected = NetConfig { ip: [192, 0, 2, 10], mask: [255, 255, 255, 0], gateway: [192, 0, 2, 1], port: 8000 };
    assert_eq!(stored().0, expected);
    let shown = request(web, "GET", "/api/v1/network", &[], "");
    assert!(shown.body.contains(r#""restart_needed":true"#), "{}", shown.body);
    assert!(shown.body.contains(r#""modbus_port":8000,"http_port":8080}"#), "{}", shown.body);

    // Not with the factory password, which anyone knows (as discovery: docs/security.md).
    let list = r#"{"networks":["192.0.2.0/24","10.9.8.7"]}"#;
    let factory = request(web, "PUT", "/api/v1/access", &page.sign("PUT", "/api/v1/access", list), list);
    expect_refused(factory, "set a password first", 403);
    // Nor a firmware upload (as the update service: docs/update.md).
    let header = "h".repeat(HEADER_LEN);
    let upload = request(web, "POST", "/api/v1/firmware", &page.sign("POST", "/api/v1/firmware", &header), &header);
    expect_refused(upload, "set a password first", 403);
    assert_eq!(stored().1 & info_flags::WRITES_RESTRICTED, 0);
    // A password change: without the module's key first, refused; then sealed and stored, and
    // the session of the old password ends.
    let early = request(web, "PUT", "/api/v1/password", &page.sign("PUT", "/api/v1/password", "{}"), "{}");
    assert_eq!(early.status, 400);
    // Sealed for a key the module no longer offers (a second offer replaced it): 409, as it
    // would open to a password nobody knows; another session cannot use this session's key.
    let older = page.password_key(web);
    let offered = page.password_key(web);
    assert_ne!(older, offered);
    let stale = page.put_password(web, &older, "correct horse", [3; 16]);
    assert_eq!((stale.status, field(&stale.body, "field")), (409, "module"), "{}", stale.body);
    let mut other = log_in(web, FACTORY_PASSWORD).unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    assert_eq!(other.put_password(web, &offered, "wrong horse", [4; 16]).status, 409, "not offered to it");
    assert_eq!(page.put_password(web, &offered, "correct horse", [3; 16]).status, 204, "the offer was kept");
    expect_refused(
        request(web, "GET", "/api/v1/access", &page.sign("GET", "/api/v1/access", ""), ""),
        "no session",
        401,
    );
    assert_eq!(log_in(web, FACTORY_PASSWORD).err().map(|a| a.status), Some(401), "the old password is gone");
    assert_eq!(stored().1 & info_flags::FACTORY_PASSWORD, 0, "discovery no longer warns of the factory password");
    let mut page = log_in(web, "correct horse").unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    // The allow-list: five networks are too many (422, nothing stored); one that leaves this
    // PC out restricts its Modbus writes (exception 01, extensions §4).
    let five = r#"{"networks":["10.0.0.0/8","10.1.0.0/16","10.2.0.0/16","10.3.0.0/16","10.4.0.0/16"]}"#;
    let refused = request(web, "PUT", "/api/v1/access", &page.sign("PUT", "/api/v1/access", five), five);
    assert_eq!((refused.status, field(&refused.body, "field")), (422, "networks"), "{}", refused.body);
    let set = request(web, "PUT", "/api/v1/access", &page.sign("PUT", "/api/v1/access", list), list);
    assert_eq!(set.status, 204, "{}", set.body);
    let shown = request(web, "GET", "/api/v1/access", &page.sign("GET", "/api/v1/access", ""), "");
    assert_eq!((shown.status, shown.body.as_str()), (200, r#"{"networks":["192.0.2.0/24","10.9.8.7/32"]}"#));
    assert_ne!(stored().1 & info_flags::WRITES_RESTRICTED, 0, "discovery says writes are restricted");
    let mut ctx = tcp::connect(module.addr).await.expect("modbus");
    let refused = ctx.write_single_coil(BIT_DO, true).await.unwrap();
    assert_eq!(refused, Err(tokio_modbus::ExceptionCode::IllegalFunction), "127.0.0.1 is outside the list");
    drop(ctx);
    let empty = r#"{"networks":[]}"#;
    let cleared = request(web, "PUT", "/api/v1/access", &page.sign("PUT", "/api/v1/access", empty), empty);
    assert_eq!(cleared.status, 204);
    assert_eq!(stored().1 & info_flags::WRITES_RESTRICTED, 0);

    // Firmware: anyone sees the version; an upload needs a signature; the host build has no
    // update partition (the QEMU board's upload: tools/browser).
    let firmware = request(web, "GET", "/api/v1/firmware", &[], "");
    assert_eq!((firmware.status, firmware.body.as_str()), (200, r#"{"firmware":"A100","updates":false,"chunk":512}"#));
    expect_refused(request(web, "POST", "/api/v1/firmware", &[], &header), "unsigned", 401);
    let short = request(web, "POST", "/api/v1/firmware", &page.sign("POST", "/api/v1/firmware", "h"), "h");
    assert_eq!((short.status, field(&short.body, "field")), (400, "header"), "{}", short.body);
    let upload = request(web, "POST", "/api/v1/firmware", &page.sign("POST", "/api/v1/firmware", &header), &header);
    expect_refused(upload, "this module takes no updates here", 503);
    let chunk = request(web, "PUT", "/api/v1/firmware/0", &page.sign("PUT", "/api/v1/firmware/0", "x"), "x");
    expect_refused(chunk, "no upload of this session", 409);

    // A signed restart: answered, then the module starts again, the stored settings in force
    // (the host build listens where its command line says, not at the stored address).
    let restart = request(web, "POST", "/api/v1/restart", &page.sign("POST", "/api/v1/restart", ""), "");
    assert_eq!(restart.status, 202, "{}", restart.body);
    module.wait_listening();
    assert_eq!(stored_at(module.discovery).0, expected, "kept over the restart");
    let shown = request(web, "GET", "/api/v1/network", &[], "");
    assert!(shown.body.contains(r#""restart_needed":false"#), "{}", shown.body);
}
