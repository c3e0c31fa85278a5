//! The web console's checks (issue #25): its API with a login and signed requests, and 50
//! connections opened at once.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use remodaq_protocol::auth;
use remodaq_protocol::m8350::BIT_DO;
use tokio::time::{sleep, timeout};
use tokio_modbus::client::Reader;

use crate::client::{connect, STEP};

/// The web console under QEMU (issue #25, docs/web.md): identity read without a login; a
/// wrong password refused (401); the factory password logs in; DO5 switched on by a signed
/// request, which Modbus reads; an unsigned request refused with nothing changed; DO5 off
/// again.
pub(crate) async fn web_console(web: SocketAddr, modbus: SocketAddr) -> Result<(), String> {
    use remodaq_board_host::testing::web::{field, log_in, request};
    let steps = tokio::task::spawn_blocking(move || {
        let identity = request(web, "GET", "/api/v1/identity", &[], "");
        if identity.status != 200 || field(&identity.body, "model") != "8350" {
            return Err(format!("identity: {} {}", identity.status, identity.body));
        }
        match log_in(web, "not the password") {
            Err(a) if a.status == 401 => {}
            Err(a) => return Err(format!("a wrong password: {} {}", a.status, a.body)),
            Ok(_) => return Err("a wrong password logged in".into()),
        }
        let mut page = log_in(web, auth::FACTORY_PASSWORD).map_err(|a| format!("login: {} {}", a.status, a.body))?;
        let on = r#"{"value":true}"#;
        let headers = page.sign("PUT", "/api/v1/do/5/state", on);
        let written = request(web, "PUT", "/api/v1/do/5/state", &headers, on);
        let unsigned = request(web, "PUT", "/api/v1/do/4/state", &[], on);
        Ok((written, unsigned, page))
    })
    .await
    .map_err(|e| e.to_string())??;
    let (written, unsigned, mut page) = steps;
    if written.status != 204 {
        return Err(format!("the signed write: {} {}", written.status, written.body));
    }
    if unsigned.status != 401 {
        return Err(format!("the unsigned write: {} {}", unsigned.status, unsigned.body));
    }
    let mut ctx = connect(modbus).await?;
    let dos = timeout(STEP, ctx.read_coils(BIT_DO, 6)).await.map_err(|_| "no answer")?.map_err(|e| e.to_string())?;
    if dos != Ok(vec![false, false, false, false, false, true]) {
        return Err(format!("Modbus reads the DOs {dos:?}: want DO5 on only"));
    }
    let _ = tokio::task::spawn_blocking(move || {
        let off = r#"{"value":false}"#;
        let headers = page.sign("PUT", "/api/v1/do/5/state", off);
        remodaq_board_host::testing::web::request(web, "PUT", "/api/v1/do/5/state", &headers, off)
    })
    .await;
    Ok(())
}

/// Issue #25's "50 parallel connections leave the module serving", on the embassy-net path: 50
/// connections to the web port, each sending half a request and holding it (more than the web
/// port's backlog holds: the rest are refused or wait). Modbus answers all the while. The
/// module holds at least two of them (its two connection tasks take one each; the backlog may
/// hold more): still open after a moment, and, half of them completed, at least two answered
/// (a web port that refused every connection but one, or took none, would leave Modbus nothing
/// to answer beside). The other half is dropped half-open, and the console answers once all
/// are gone.
pub(crate) async fn fifty_connections(web: SocketAddr, modbus: SocketAddr) -> Result<(), String> {
    use remodaq_board_host::testing::web::request;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let started = Instant::now();
    let mut opened = Vec::new();
    for _ in 0..50 {
        if let Ok(Ok(mut s)) = timeout(STEP, tokio::net::TcpStream::connect(web)).await {
            let _ = s.write_all(b"GET /api/v1/identity HTTP/1.1\r\nHost: ").await;
            opened.push(s);
        }
    }
    let connected = started.elapsed();
    // QEMU's user network takes every connection on this side before the guest answers its
    // SYN; a connection the guest refuses (a reset) it closes here at once. After a moment,
    // one still open and silent may be held by the module (a task has it, or the backlog holds
    // its SYN); one closed (or answered: the half request cannot be) the module did not take.
    sleep(Duration::from_millis(500)).await;
    let (mut held, mut closed) = (Vec::new(), 0);
    for s in opened.drain(..) {
        let mut byte = [0u8; 1];
        match s.try_read(&mut byte) {
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => held.push(s),
            _ => closed += 1,
        }
    }
    println!(
        "  50 connections to the web port in {connected:?}: {} open after 0.5 s, {closed} closed by the module, {} not connected",
        held.len(),
        50 - held.len() - closed
    );
    if held.len() < 2 {
        return Err(format!(
            "{} of 50 connections left open by the module ({closed} closed at once): at least its two connection tasks' wanted",
            held.len()
        ));
    }
    let mut ctx = connect(modbus).await?;
    for i in 0..20 {
        timeout(STEP, ctx.read_coils(BIT_DO, 6))
            .await
            .map_err(|_| format!("Modbus read {i} beside {} held web connections: no answer", held.len()))?
            .map_err(|e| e.to_string())?
            .map_err(|e| format!("Modbus read {i}: exception {e:?}"))?;
    }
    // Every other connection completed: those the module holds are answered (the two its
    // tasks have at once, then those of the backlog as the tasks come free); the rest dropped
    // half-open.
    let completed: Vec<_> = held.into_iter().step_by(2).collect();
    let tried = completed.len();
    let answers = completed.into_iter().map(|mut s| async move {
        s.write_all(b"127.0.0.1\r\n\r\n").await.ok()?;
        let mut head = [0u8; 12];
        timeout(Duration::from_secs(15), s.read_exact(&mut head)).await.ok()?.ok()?;
        head.starts_with(b"HTTP/1.1 200").then_some(())
    });
    let answered = futures_all(answers).await.into_iter().flatten().count();
    println!("  {tried} of the held connections completed: {answered} answered 200 within 15 s");
    if answered < 2 {
        return Err(format!(
            "{answered} of {tried} held connections answered once their requests were completed: the module held fewer than two"
        ));
    }
    // Each held connection ends at its close, or at the module's timeouts (docs/web.md).
    let status = tokio::task::spawn_blocking(move || {
        let back = Instant::now();
        loop {
            let status = request(web, "GET", "/api/v1/identity", &[], "").status;
            if status == 200 || back.elapsed() > Duration::from_secs(60) {
                return status;
            }
            std::thread::sleep(Duration::from_millis(500));
        }
    })
    .await
    .map_err(|e| e.to_string())?;
    if status != 200 {
        return Err(format!("the console after the 50 connections: status {status}"));
    }
    Ok(())
}

/// Runs `futures` at once (each in its own task); their outputs in order.
async fn futures_all<F>(futures: impl IntoIterator<Item = F>) -> Vec<F::Output>
where
    F: std::future::Future + Send + 'static,
    F::Output: Send + 'static,
{
    let tasks: Vec<_> = futures.into_iter().map(tokio::spawn).collect();
    let mut outputs = Vec::new();
    for task in tasks {
        if let Ok(output) = task.await {
            outputs.push(output);
        }
    }
    outputs
}
