//! The discovery checks (UDP, through the forwarded port): search, authenticated commands,
//! new network settings and a restart, and setting this test's password.

use std::net::SocketAddr;
use std::time::Duration;

use remodaq_protocol::diag;
use remodaq_protocol::discovery::client::{transact, Ask};
use remodaq_protocol::discovery::{decode_info, encode_request, Request, Status, MAX_DATAGRAM};
use remodaq_protocol::m8318::REG_INPUT_TYPE;
use remodaq_protocol::net::NetConfig;
use tokio::time::{sleep, timeout};

use crate::client::{regs, wait_ready};

/// One discovery request (UDP) and its reply, at most 3 tries of 2 s.
pub(crate) async fn discover(to: SocketAddr, request: &[u8]) -> Result<Vec<u8>, String> {
    let socket = tokio::net::UdpSocket::bind("127.0.0.1:0").await.map_err(|e| e.to_string())?;
    let mut rx = [0u8; 512];
    for _ in 0..3 {
        socket.send_to(request, to).await.map_err(|e| e.to_string())?;
        if let Ok(Ok((n, _))) = timeout(Duration::from_secs(2), socket.recv_from(&mut rx)).await {
            return Ok(rx[..n].to_vec());
        }
    }
    Err(format!("no discovery reply from {to}"))
}

/// The password the update checks set (updates are refused while the factory one is in force).
pub(crate) const PASSWORD: &str = "qemu-e2e password";

/// One authenticated discovery command (challenge, proof, signed answer) over a blocking UDP
/// socket, in a blocking task; its status.
async fn command(to: SocketAddr, mac: [u8; 6], password: &'static str, ask: Ask<'static>) -> Result<Status, String> {
    tokio::task::spawn_blocking(move || {
        let socket = std::net::UdpSocket::bind("127.0.0.1:0").map_err(|e| e.to_string())?;
        socket.set_read_timeout(Some(Duration::from_secs(2))).map_err(|e| e.to_string())?;
        let send = |bytes: &[u8]| {
            let mut rx = [0u8; 512];
            for _ in 0..3 {
                socket.send_to(bytes, to).ok()?;
                if let Ok((n, _)) = socket.recv_from(&mut rx) {
                    return Some(rx[..n].to_vec());
                }
            }
            None
        };
        let cnonce = std::process::id().to_be_bytes().repeat(4).try_into().unwrap_or([1; 16]);
        transact(mac, password.as_bytes(), ask, cnonce, 40, send)
            .map(|(reply, _)| reply.status)
            .map_err(|e| format!("discovery command: {e:?}"))
    })
    .await
    .map_err(|e| e.to_string())?
}

/// The embassy-net discovery path end to end: search, store new network settings with the
/// password, restart (a system reset of the guest), then the module answers again with the
/// stored settings and the input type written before (the settings region survives a reset).
pub(crate) async fn discovery_and_restart(to: SocketAddr, modbus: SocketAddr, model: u16) -> Result<(), String> {
    let mut buf = [0u8; MAX_DATAGRAM];
    let n = encode_request(7, &Request::Search, &mut buf).ok_or("search")?;
    let reply = discover(to, &buf[..n]).await?;
    let info = decode_info(&reply).ok_or("search: not an INFO reply")?;
    if info.model != model || info.id != 7 || info.running.ip != [10, 0, 2, 15] {
        return Err(format!("search: {info:?}"));
    }
    let mac = info.mac;
    let net = NetConfig { ip: [10, 0, 0, 50], mask: [255, 255, 0, 0], gateway: [10, 0, 0, 1], port: 8000 };
    // The manuals' first contact: the factory password sets the network and restarts.
    let status = command(to, mac, "remodaq", Ask::SetNetwork(net)).await?;
    if status != Status::Ok {
        return Err(format!("set network: {status:?}"));
    }
    let status = command(to, mac, "remodaq", Ask::Restart).await?;
    if status != Status::Ok {
        return Err(format!("restart: {status:?}"));
    }
    sleep(Duration::from_secs(1)).await;
    let mut ctx = wait_ready(modbus).await?;
    let n = encode_request(10, &Request::Search, &mut buf).ok_or("search")?;
    let reply = discover(to, &buf[..n]).await?;
    let info = decode_info(&reply).ok_or("search after restart")?;
    if info.stored != net || info.uptime_s > 30 {
        return Err(format!("after the restart: stored {:?}, up {} s", info.stored, info.uptime_s));
    }
    let cause = regs(&mut ctx, diag::REG_RESET_CAUSE, 1).await?;
    if cause != [diag::reset_cause::SOFTWARE] {
        return Err(format!("reset cause after the restart: {cause:?}, expected 2 (software)"));
    }
    if model == 0x8318 {
        let t = regs(&mut ctx, REG_INPUT_TYPE, 1).await?;
        if t != [0x0E] {
            return Err(format!("input type after the restart: {t:x?}, written 0e before"));
        }
    }
    Ok(())
}

/// Sets this test's password over discovery (updates are refused under the factory one); the
/// module's MAC.
pub(crate) async fn set_password(discovery: SocketAddr) -> Result<[u8; 6], String> {
    let mut buf = [0u8; MAX_DATAGRAM];
    let n = encode_request(12, &Request::Search, &mut buf).unwrap_or(0);
    let mac = match discover(discovery, &buf[..n]).await.map(|reply| decode_info(&reply).map(|i| i.mac)) {
        Ok(Some(mac)) => mac,
        other => return Err(format!("search: {other:?}")),
    };
    let set = Ask::SetPassword { new: PASSWORD.as_bytes(), salt: [0x33; 16], iterations: 4096, secret: [0x44; 32] };
    match command(discovery, mac, "remodaq", set).await {
        Ok(Status::Ok) => Ok(mac),
        other => Err(format!("setting the password: {other:?}")),
    }
}
