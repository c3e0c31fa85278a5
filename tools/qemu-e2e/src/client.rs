//! The Modbus client every check goes through: a connection, reads and writes with each wait
//! bounded, and waiting until a booting guest answers.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use remodaq_protocol::diag;
use remodaq_protocol::identity::REG_NAME;
use tokio::time::{sleep, timeout};
use tokio_modbus::client::{tcp, Context, Reader, Writer as _};

pub(crate) const STEP: Duration = Duration::from_secs(5);
const BOOT: Duration = Duration::from_secs(90);

pub(crate) async fn connect(addr: SocketAddr) -> Result<Context, String> {
    timeout(STEP, tcp::connect(addr)).await.map_err(|_| "connect timed out".to_string())?.map_err(|e| e.to_string())
}

pub(crate) async fn regs(ctx: &mut Context, addr: u16, n: u16) -> Result<Vec<u16>, String> {
    let r = timeout(STEP, ctx.read_holding_registers(addr, n)).await.map_err(|_| "no answer in time".to_string())?;
    r.map_err(|e| e.to_string())?.map_err(|e| format!("exception {e:?}"))
}

pub(crate) async fn write(ctx: &mut Context, addr: u16, values: &[u16]) -> Result<(), String> {
    let r =
        timeout(STEP, ctx.write_multiple_registers(addr, values)).await.map_err(|_| "no answer in time".to_string())?;
    r.map_err(|e| e.to_string())?.map_err(|e| format!("exception {e:?}"))
}

/// Ready when the guest answers a request (QEMU accepts the TCP connection before the guest
/// listens, so only an exchange of data tells).
pub(crate) async fn wait_ready(addr: SocketAddr) -> Result<Context, String> {
    let deadline = Instant::now() + BOOT;
    loop {
        if let Ok(mut ctx) = connect(addr).await {
            if timeout(Duration::from_secs(2), ctx.read_holding_registers(REG_NAME, 1))
                .await
                .is_ok_and(|r| r.is_ok_and(|r| r.is_ok()))
            {
                return Ok(ctx);
            }
        }
        if Instant::now() > deadline {
            return Err(format!("no Modbus answer within {} s", BOOT.as_secs()));
        }
        sleep(Duration::from_millis(500)).await;
    }
}

/// Reads `n` registers from `addr` until `ok` accepts them (at most 3 s: a few acquisition
/// cycles after a setting changed).
pub(crate) async fn regs_until(
    ctx: &mut Context,
    addr: u16,
    n: u16,
    ok: impl Fn(&[u16]) -> bool,
) -> Result<Vec<u16>, String> {
    let deadline = Instant::now() + Duration::from_secs(3);
    loop {
        let v = regs(ctx, addr, n).await?;
        if ok(&v) || Instant::now() > deadline {
            return Ok(v);
        }
        sleep(Duration::from_millis(100)).await;
    }
}

/// A diagnostics register.
pub(crate) async fn diag_reg(ctx: &mut Context, d: diag::Diag) -> Result<u16, String> {
    Ok(regs(ctx, d.addr(), 1).await?[0])
}

/// The module's uptime, s (40242-40243).
pub(crate) async fn uptime(ctx: &mut Context) -> Result<u32, String> {
    let w = regs(ctx, diag::REG_UPTIME, 2).await?;
    Ok(u32::from(w[0]) | u32::from(w[1]) << 16)
}
