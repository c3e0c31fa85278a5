//! An update session by hand (the handshake, the image, each answer's signature checked), and
//! the firmware version the module answers after an update's restart.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use remodaq_protocol::auth;
use remodaq_protocol::discovery::Status;
use remodaq_protocol::identity::REG_VERSION;
use remodaq_protocol::update::{answer_message, auth_message, Greeting, GREETING_LEN, HEADER_LEN, OPENING};
use tokio::time::{sleep, timeout};

use crate::client::{connect, regs, STEP};

/// The firmware version register, once the module answers (after a restart: up to 60 s).
pub(crate) async fn version(addr: SocketAddr) -> Result<u16, String> {
    let started = Instant::now();
    loop {
        if let Ok(mut ctx) = connect(addr).await {
            if let Ok(v) = regs(&mut ctx, REG_VERSION, 1).await {
                return Ok(v[0]);
            }
        }
        if started.elapsed() > Duration::from_secs(60) {
            return Err("the module did not answer within 60 s".into());
        }
        sleep(Duration::from_millis(500)).await;
    }
}

/// Waits until the module answered version `trial` and then `previous` again (a new image that
/// ran on trial and was reverted), at most 90 s; how long that took.
pub(crate) async fn reverted(addr: SocketAddr, trial: u16, previous: u16) -> Result<Duration, String> {
    let started = Instant::now();
    let mut saw_trial = false;
    loop {
        match version(addr).await? {
            v if v == trial => saw_trial = true,
            v if v == previous && saw_trial => return Ok(started.elapsed()),
            _ => {}
        }
        if started.elapsed() > Duration::from_secs(90) {
            return Err(format!("no return to {previous:04X} within 90 s ({trial:04X} seen: {saw_trial})"));
        }
        sleep(Duration::from_millis(500)).await;
    }
}

/// An update session by hand with `password`: the handshake, `file` (cut after `send`
/// bytes); the statuses the module answered (each signature checked).
pub(crate) async fn session(update: SocketAddr, password: &str, file: &[u8], send: usize) -> Result<Vec<u8>, String> {
    paced_session(update, password, file, send, None).await
}

/// [`session`], the firmware sent `pace.0` bytes at a time with `pace.1` between them (a slow
/// PC, so that a session lasts long enough to watch the module during it).
pub(crate) async fn paced_session(
    update: SocketAddr,
    password: &str,
    file: &[u8],
    send: usize,
    pace: Option<(usize, Duration)>,
) -> Result<Vec<u8>, String> {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let cnonce = [0x5C; 16];
    // The module serves one session at a time and listens again a moment after one ends: a
    // connection reset before the greeting is tried again, for a few seconds (as remodaq does).
    let started = Instant::now();
    let (mut stream, greeting) = loop {
        let attempt = async {
            let mut stream = timeout(STEP, tokio::net::TcpStream::connect(update))
                .await
                .map_err(|_| "update service: connect timed out".to_string())?
                .map_err(|e| e.to_string())?;
            stream.write_all(&[&OPENING[..], &cnonce[..]].concat()).await.map_err(|e| e.to_string())?;
            let mut greeting = [0u8; GREETING_LEN];
            timeout(STEP, stream.read_exact(&mut greeting))
                .await
                .map_err(|_| "no greeting".to_string())?
                .map_err(|e| e.to_string())?;
            Ok::<_, String>((stream, Greeting::decode(&greeting)))
        };
        match attempt.await {
            Ok(connected) => break connected,
            Err(e) if started.elapsed() > Duration::from_secs(10) => return Err(e),
            Err(_) => sleep(Duration::from_millis(300)).await,
        }
    };
    let (client_key, credential) = auth::derive(password.as_bytes(), &greeting.salt, greeting.iterations);
    let mut header = [0u8; HEADER_LEN];
    header.copy_from_slice(&file[..HEADER_LEN]);
    let message = auth_message(&greeting.mac, &cnonce, &greeting.snonce, &header);
    let proof = auth::client_proof(&client_key, &message);
    let send = send.min(file.len());
    // The proof and the header; the firmware only once the module said go on (a refusal
    // closes the connection: bytes still arriving would reset it before the answer is read).
    stream.write_all(&[&proof[..], &header[..]].concat()).await.map_err(|e| e.to_string())?;
    let mut answers = Vec::new();
    for step in 0..2u8 {
        let mut status = [0u8; 1];
        let limit = if step == 0 { STEP * 4 } else { Duration::from_secs(60) };
        match timeout(limit, stream.read_exact(&mut status)).await {
            Ok(Ok(_)) => answers.push(status[0]),
            _ => break,
        }
        if Status::from_code(status[0]).is_some_and(Status::after_proof) {
            let mut signature = [0u8; 32];
            timeout(STEP, stream.read_exact(&mut signature))
                .await
                .map_err(|_| "no signature".to_string())?
                .map_err(|e| e.to_string())?;
            let expected = auth::server_signature(&credential.server_key, &answer_message(&message, &[step], &status));
            if !auth::same(&expected, &signature) {
                return Err(format!("answer {step}: not signed by the module"));
            }
        }
        if status[0] != 0 || step == 1 {
            break;
        }
        match pace {
            None => stream.write_all(&file[HEADER_LEN..send]).await.map_err(|e| e.to_string())?,
            Some((chunk, every)) => {
                for part in file[HEADER_LEN..send].chunks(chunk) {
                    stream.write_all(part).await.map_err(|e| e.to_string())?;
                    sleep(every).await;
                }
            }
        }
        if send < file.len() {
            // Cut: close without the rest.
            break;
        }
    }
    Ok(answers)
}
