//! `remodaq update`: sends a signed image file to a module's update service (TCP port 8301,
//! docs/update.md) with a progress bar, then waits for the module to restart into it and shows
//! the firmware version before and after.

use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};

use remodaq_protocol::update::{Header, Status, HEADER_LEN};
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
        Some(Status::Ok) | None => Error::Reply(format!("{module}: not an update service answer")),
    }
}

async fn status(stream: &mut TcpStream, limit: Duration, module: SocketAddr) -> Result<Status, Error> {
    let mut byte = [0u8; 1];
    match within(limit, stream.read_exact(&mut byte)).await {
        Ok(Ok(_)) => Ok(Status::from_code(byte[0]).ok_or_else(|| refused(None, module))?),
        Ok(Err(e)) => Err(Error::Other(format!("{module}: the update service closed the connection ({e})"))),
        Err(_) => {
            Err(Error::Timeout(format!("{module}: no answer from the update service within {} s", limit.as_secs())))
        }
    }
}

/// `remodaq update MODULE IMAGE --password PW`.
pub async fn update(
    module: &str,
    image: &Path,
    password: &str,
    port: u16,
    timeout: Duration,
    json: bool,
) -> Result<(), Error> {
    let file = std::fs::read(image).map_err(|e| Error::Other(format!("cannot read {}: {e}", image.display())))?;
    let header = file
        .first_chunk::<HEADER_LEN>()
        .and_then(Header::decode)
        .filter(|h| h.length as usize == file.len() - HEADER_LEN)
        .ok_or_else(|| Error::Other(format!("{} is not a signed image file (remodaq sign)", image.display())))?;
    if password.len() > remodaq_protocol::discovery::MAX_PASSWORD_LEN {
        return Err(Error::Other("password too long".into()));
    }
    let (addr, model, before) = crate::io::identity(module, timeout).await?;
    if model != header.model {
        return Err(Error::Other(format!("the image is for a {:04X}, the module is a {model:04X}", header.model)));
    }
    let target = SocketAddr::new(addr.ip(), port);
    let mut hello = vec![password.len() as u8];
    hello.extend_from_slice(password.as_bytes());
    hello.extend_from_slice(&file[..HEADER_LEN]);
    let io_error = |e: std::io::Error| Error::Other(format!("{target}: {e}"));
    // The module serves one session at a time and listens again a moment after one ends:
    // a connection refused or reset before the first answer is tried again, for a few seconds.
    let started = Instant::now();
    let mut stream = loop {
        let attempt = async {
            let mut stream = within(timeout, TcpStream::connect(target))
                .await
                .map_err(|_| Error::Timeout(format!("no connection to the update service at {target}")))?
                .map_err(|e| Error::Other(format!("cannot connect to the update service at {target}: {e}")))?;
            stream.write_all(&hello).await.map_err(io_error)?;
            // The module erases its update partition before it answers.
            let first = status(&mut stream, ERASE, target).await?;
            Ok::<_, Error>((stream, first))
        };
        match attempt.await {
            Ok((stream, Status::Ok)) => break stream,
            Ok((_, other)) => return Err(refused(Some(other), target)),
            Err(e) if started.elapsed() > Duration::from_secs(10) => return Err(e),
            Err(_) => tokio::time::sleep(Duration::from_millis(300)).await,
        }
    };
    let bar =
        if json { indicatif::ProgressBar::hidden() } else { indicatif::ProgressBar::new(u64::from(header.length)) };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {bytes}/{total_bytes} {bytes_per_sec} {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    for chunk in file[HEADER_LEN..].chunks(4096) {
        stream.write_all(chunk).await.map_err(io_error)?;
        bar.inc(chunk.len() as u64);
    }
    bar.set_message("verifying");
    let verdict = status(&mut stream, VERIFY, target).await;
    bar.finish_and_clear();
    match verdict? {
        Status::Ok => {}
        other => return Err(refused(Some(other), target)),
    }
    if !json {
        println!("{addr}: version {:04X} verified and marked; the module restarts into it", header.version);
    }
    // The restart: the bootloader swaps the image in, then it must answer with its version.
    let started = Instant::now();
    let after = loop {
        tokio::time::sleep(Duration::from_secs(1)).await;
        if let Ok((_, _, version)) = crate::io::identity(module, timeout).await {
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
    if json {
        let out = serde_json::json!({ "module": addr.to_string(), "before": format!("{before:04X}"), "after": format!("{after:04X}") });
        println!("{out}");
    } else {
        println!("{addr}: firmware {before:04X} -> {after:04X}");
    }
    Ok(())
}
