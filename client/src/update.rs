//! A firmware update: sends a signed image file to a module's update service (TCP port 8301,
//! docs/update.md), saying how far it got, then waits for the module to restart into it and
//! gives the firmware version before and after.

use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};

use remodaq_protocol::auth;
use remodaq_protocol::update::{
    answer_message, auth_message, Greeting, Header, Status, GREETING_LEN, HEADER_LEN, OPENING,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::time::timeout as within;

use crate::Error;

/// How long the module may take to verify the image once it has all of it (the hash is read
/// back from the update partition).
const VERIFY: Duration = Duration::from_secs(120);
/// How long the module may take to erase its update partition before it answers the header.
const ERASE: Duration = Duration::from_secs(60);
/// How long the restart into the new image (the bootloader's swap, the self-test) may take.
const RESTART: Duration = Duration::from_secs(120);

fn refused(status: Option<Status>, module: SocketAddr) -> Error {
    match status {
        Some(Status::WrongPassword) => Error::Refused(format!("{module}: wrong password, nothing changed")),
        Some(Status::RateLimited) => Error::Refused(format!("{module}: too many wrong passwords, try again later")),
        Some(Status::Invalid) => {
            Error::Other(format!("{module}: not an image for this module (model, size or format)"))
        }
        Some(Status::BadSignature) => Error::Other(format!(
            "{module}: the signature does not match (another key, or a changed file); nothing changed"
        )),
        Some(Status::StoreFailed) => Error::Other(format!("{module}: the module could not write the update")),
        Some(Status::Downgrade) => Error::Refused(format!(
            "{module}: the image's security counter is below the module's (an older release); nothing changed"
        )),
        Some(Status::StaleNonce) => Error::Reply(format!("{module}: not an update service answer")),
        Some(Status::SetPasswordFirst) => Error::Refused(format!(
            "{module}: the factory password is in force: set a password first (remodaq password); nothing changed"
        )),
        Some(Status::Ok | Status::CommitBudget) | None => {
            Error::Reply(format!("{module}: not an update service answer"))
        }
    }
}

async fn read(stream: &mut TcpStream, buf: &mut [u8], limit: Duration, module: SocketAddr) -> Result<(), Error> {
    match within(limit, stream.read_exact(buf)).await {
        Ok(Ok(_)) => Ok(()),
        Ok(Err(e)) => Err(Error::Other(format!("{module}: the update service closed the connection ({e})"))),
        Err(_) => {
            Err(Error::Timeout(format!("{module}: no answer from the update service within {} s", limit.as_secs())))
        }
    }
}

/// What the PC knows of a session once it sent its proof.
struct Session {
    server_key: [u8; 32],
    mac: [u8; 6],
    cnonce: [u8; 16],
    snonce: [u8; 16],
    header: [u8; HEADER_LEN],
}

/// The module's answer at `step` (0 after the header, 1 after the firmware): its status, whose
/// signature must be the module's when it comes after a right proof.
async fn status(
    stream: &mut TcpStream,
    session: &Session,
    step: u8,
    limit: Duration,
    module: SocketAddr,
) -> Result<Status, Error> {
    let mut byte = [0u8; 1];
    read(stream, &mut byte, limit, module).await?;
    let status = Status::from_code(byte[0]).ok_or_else(|| refused(None, module))?;
    if status.after_proof() {
        let mut signature = [0u8; 32];
        read(stream, &mut signature, limit, module).await?;
        let message = auth_message(&session.mac, &session.cnonce, &session.snonce, &session.header);
        let expected = auth::server_signature(&session.server_key, &answer_message(&message, &[step], &byte));
        if !auth::same(&expected, &signature) {
            return Err(Error::Reply(format!("{module}: the answer is not signed by the module (a forged answer?)")));
        }
    }
    Ok(status)
}

/// How far an update got.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Progress {
    /// Bytes of the firmware sent, of the total.
    Sent(u64, u64),
    /// All sent: the module verifies the signature.
    Verifying,
    /// Verified and marked: the module (at this address) restarts into this version.
    Restarting(SocketAddr, u16),
}

/// An update that went through.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Updated {
    pub module: SocketAddr,
    pub before: u16,
    pub after: u16,
}

/// Reads and checks a signed image file (`remodaq sign`).
pub fn read_image(image: &Path) -> Result<(Vec<u8>, Header), Error> {
    let file = std::fs::read(image).map_err(|e| Error::Other(format!("cannot read {}: {e}", image.display())))?;
    let header = file
        .first_chunk::<HEADER_LEN>()
        .and_then(Header::decode)
        .filter(|h| h.length as usize == file.len() - HEADER_LEN)
        .ok_or_else(|| Error::Other(format!("{} is not a signed image file (remodaq sign)", image.display())))?;
    Ok((file, header))
}

/// Updates the module at `module` with the image file `image` (its update service on `port`),
/// telling `progress` how far it got. With `mac` (the module the user chose, as a search
/// found it), the session goes on only if the update service there greets as that module: the
/// proof covers the greeting's MAC, so it is bound to the module the user named, and a
/// redirector cannot relay it to another module that shares the password (security review
/// finding 15a).
pub async fn update(
    module: &str,
    mac: Option<crate::lan::Mac>,
    image: &Path,
    password: &str,
    port: u16,
    timeout: Duration,
    mut progress: impl FnMut(Progress),
) -> Result<Updated, Error> {
    let (file, header) = read_image(image)?;
    let (addr, model, before) = crate::modbus::identity(module, timeout).await?;
    if model != header.model {
        return Err(Error::Other(format!("the image is for a {:04X}, the module is a {model:04X}", header.model)));
    }
    let target = SocketAddr::new(addr.ip(), port);
    let mut header_bytes = [0u8; HEADER_LEN];
    header_bytes.copy_from_slice(&file[..HEADER_LEN]);
    let io_error = |e: std::io::Error| Error::Other(format!("{target}: {e}"));
    // The module serves one session at a time and listens again a moment after one ends:
    // a connection refused or reset before the first answer is tried again, for a few seconds.
    let started = Instant::now();
    let (mut stream, session) = loop {
        let attempt = async {
            let mut stream = within(timeout, TcpStream::connect(target))
                .await
                .map_err(|_| Error::Timeout(format!("no connection to the update service at {target}")))?
                .map_err(|e| Error::Other(format!("cannot connect to the update service at {target}: {e}")))?;
            let cnonce = crate::lan::random::<16>()?;
            let mut opening = [0u8; OPENING.len() + 16];
            opening[..OPENING.len()].copy_from_slice(&OPENING);
            opening[OPENING.len()..].copy_from_slice(&cnonce);
            stream.write_all(&opening).await.map_err(io_error)?;
            let mut greeting = [0u8; GREETING_LEN];
            read(&mut stream, &mut greeting, timeout, target).await?;
            let greeting = Greeting::decode(&greeting);
            if let Some(mac) = mac.filter(|m| m.0 != greeting.mac) {
                return Err(Error::Refused(format!(
                    "{target}: the update service there is module {}, not {mac}: nothing sent",
                    crate::lan::Mac(greeting.mac)
                )));
            }
            let (client_key, credential) =
                crate::lan::login_blocking(password, &greeting.salt, greeting.iterations).await?;
            let session = Session {
                server_key: credential.server_key,
                mac: greeting.mac,
                cnonce,
                snonce: greeting.snonce,
                header: header_bytes,
            };
            let message = auth_message(&session.mac, &cnonce, &session.snonce, &header_bytes);
            let proof = auth::client_proof(&client_key, &message);
            stream.write_all(&[&proof[..], &header_bytes[..]].concat()).await.map_err(io_error)?;
            // The module erases its update partition before it answers.
            let first = status(&mut stream, &session, 0, ERASE, target).await?;
            Ok::<_, Error>((stream, session, first))
        };
        match attempt.await {
            Ok((stream, session, Status::Ok)) => break (stream, session),
            Ok((_, _, other)) => return Err(refused(Some(other), target)),
            Err(e) if started.elapsed() > Duration::from_secs(10) => return Err(e),
            Err(_) => tokio::time::sleep(Duration::from_millis(300)).await,
        }
    };
    let (mut sent, total) = (0u64, u64::from(header.length));
    for chunk in file[HEADER_LEN..].chunks(4096) {
        stream.write_all(chunk).await.map_err(io_error)?;
        sent += chunk.len() as u64;
        progress(Progress::Sent(sent, total));
    }
    progress(Progress::Verifying);
    match status(&mut stream, &session, 1, VERIFY, target).await? {
        Status::Ok => {}
        other => return Err(refused(Some(other), target)),
    }
    progress(Progress::Restarting(addr, header.version));
    // The restart: the bootloader swaps the image in, then it must answer with its version.
    let started = Instant::now();
    let after = loop {
        tokio::time::sleep(Duration::from_secs(1)).await;
        if let Ok((_, _, version)) = crate::modbus::identity(module, timeout).await {
            if version == header.version {
                break version;
            }
        }
        if started.elapsed() > RESTART {
            return Err(Error::Timeout(format!(
                "{addr} did not come back with version {:04X} within {} s (it may have reverted)",
                header.version,
                RESTART.as_secs()
            )));
        }
    };
    Ok(Updated { module: addr, before, after })
}
