//! The checks of the extensions: the host watchdog (§3), the diagnostics' injected front-end
//! fault (§1), and the latency of an output command (issue #23).

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use remodaq_protocol::diag;
use remodaq_protocol::m8350::{
    wd_mode, BIT_DO, REG_ALL_DO, REG_SAFE_VALUES, REG_WD_MODE, REG_WD_STATUS, REG_WD_TIMEOUT,
};
use tokio::time::{sleep, timeout};
use tokio_modbus::client::{Context, Reader, Writer as _};

use crate::client::{connect, diag_reg, regs, uptime, wait_ready, write, STEP};

/// Extensions §3 through the emulated NIC: a 0.5 s host watchdog fed by writes only, armed by
/// a write, trips (reads do not feed it): the DOs take their safe levels and a write to the
/// outputs answers exception 04; writing 0 to the status clears it. The timing comes from the
/// module's clock (SysTick under QEMU).
pub(crate) async fn host_watchdog(addr: SocketAddr) -> Result<Duration, String> {
    // Right after the 64-connection flood QEMU's user network may still reset a new connection:
    // the first exchange is retried as at boot.
    let mut ctx = wait_ready(addr).await?;
    write(&mut ctx, REG_SAFE_VALUES, &[0b00_0101]).await?;
    write(&mut ctx, REG_WD_MODE, &[wd_mode::WRITES_ONLY]).await?;
    let armed = Instant::now();
    write(&mut ctx, REG_WD_TIMEOUT, &[5]).await?;
    let arm_answered = armed.elapsed();
    // The trip lies after the last read that still saw the watchdog running was sent and
    // before the first read that saw the trip was answered; the arming write took effect
    // between its sending and its answer. So the module's trip time lies in
    // [last_running - arm_answered, tripped]: a check that fails only when the module
    // provably tripped outside the spec's 500-600 ms, however slow this machine is.
    let mut last_running = Duration::ZERO;
    let tripped = loop {
        let sent = armed.elapsed();
        if regs(&mut ctx, REG_WD_STATUS, 1).await? == [1] {
            break armed.elapsed();
        }
        last_running = sent;
        if armed.elapsed() > Duration::from_secs(3) {
            return Err("no trip within 3 s".into());
        }
        sleep(Duration::from_millis(2)).await;
    };
    let earliest = last_running.saturating_sub(arm_answered);
    println!("  the trip lies between {earliest:?} and {tripped:?} after the arming write");
    if tripped < Duration::from_millis(500) || earliest > Duration::from_millis(600) {
        return Err(format!(
            "tripped between {earliest:?} and {tripped:?} after the arming write, spec 500-600 ms (0.5 s, +0.1 s)"
        ));
    }
    let dos = timeout(STEP, ctx.read_coils(BIT_DO, 6)).await.map_err(|_| "coils: no answer".to_string())?;
    let dos = dos.map_err(|e| e.to_string())?.map_err(|e| format!("coils: exception {e:?}"))?;
    if dos != [true, false, true, false, false, false] {
        return Err(format!("DO levels {dos:?}, expected the safe levels 000101"));
    }
    match write(&mut ctx, REG_ALL_DO, &[0]).await {
        Err(e) if e.contains("ServerDeviceFailure") => {}
        other => return Err(format!("writing the outputs while tripped: {other:?}, expected exception 04")),
    }
    write(&mut ctx, REG_WD_STATUS, &[0]).await?;
    if regs(&mut ctx, REG_WD_STATUS, 1).await? != [0] {
        return Err("still tripped after the clear".into());
    }
    write(&mut ctx, REG_WD_TIMEOUT, &[0]).await?;
    write(&mut ctx, REG_ALL_DO, &[0]).await?;
    Ok(tripped)
}

/// Extensions §1 through the emulated NIC: the QEMU board injects a front-end fault from 20 s
/// to 23 s after its start (after the other checks) (8318: conversions fail; 8350: input samples lost); module status
/// bit 0 shows it, then clears. The reset cause of this first start is power-on (0).
pub(crate) async fn diagnostics(addr: SocketAddr) -> Result<(), String> {
    let mut ctx = connect(addr).await?;
    let d = regs(&mut ctx, diag::REG_MODULE_STATUS, 8).await?;
    if d[3] != diag::reset_cause::POWER_ON || d[4] == 0 {
        return Err(format!("diagnostics {d:04x?}: reset cause 0 and this client expected"));
    }
    let status = async |ctx: &mut Context| regs(ctx, diag::REG_MODULE_STATUS, 1).await.map(|v| v[0]);
    // Watched from a second before the injection, after one read: the 8350's bit stays set
    // until read after a loss, and this PC keeping QEMU from running for longer than the
    // capture ring lasts (82 ms, seen twice in a busy hour here) loses samples as the injected
    // fault does (the update check holds the firmware to losing none).
    let deadline = Instant::now() + Duration::from_secs(40);
    while uptime(&mut ctx).await? < 19 {
        if Instant::now() > deadline {
            return Err("the uptime never reached 19 s".into());
        }
        sleep(Duration::from_millis(200)).await;
    }
    status(&mut ctx).await?;
    while status(&mut ctx).await? & diag::status::FRONT_END_FAULT == 0 {
        if Instant::now() > deadline {
            return Err("the injected fault never showed in 40241".into());
        }
        sleep(Duration::from_millis(200)).await;
    }
    let up = regs(&mut ctx, diag::REG_UPTIME, 2).await?;
    if !(20..24).contains(&up[0]) || up[1] != 0 {
        return Err(format!("fault seen at uptime {up:?}, injected from 20 to 23 s"));
    }
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        // Two clean reads in a row: the 8350's bit is cleared by a read after the last loss.
        if status(&mut ctx).await? == 0 && status(&mut ctx).await? == 0 {
            return Ok(());
        }
        if Instant::now() > deadline {
            return Err("the fault never cleared".into());
        }
        sleep(Duration::from_millis(200)).await;
    }
}

/// The goal of issue #23 for an output command, write to pin: 1 ms.
const OUTPUT_LATENCY_GOAL_US: u16 = 1000;

/// `writes` DO0 writes (05), alternately on and off, each followed after 15 ms (more than the
/// 12.8 ms a refill can take) by a read of the module's own measure of that write's latency
/// (40326); the median, the 95th percentile and the worst, µs.
pub(crate) async fn output_latency(addr: SocketAddr, writes: u32) -> Result<(u16, u16, u16), String> {
    let mut ctx = connect(addr).await?;
    let mut seen = Vec::new();
    for i in 0..writes {
        timeout(STEP, ctx.write_single_coil(BIT_DO, i % 2 == 0))
            .await
            .map_err(|_| "no answer in time".to_string())?
            .map_err(|e| e.to_string())?
            .map_err(|e| format!("DO0 write: exception {e:?}"))?;
        sleep(Duration::from_millis(15)).await;
        seen.push(diag_reg(&mut ctx, diag::Diag::OutputLatency).await?);
    }
    seen.sort_unstable();
    let at = |part: usize| seen.get(seen.len() * part / 100).copied();
    let (Some(median), Some(p95), Some(&worst)) = (at(50), at(95), seen.last()) else {
        return Err("no writes".into());
    };
    Ok((median, p95, worst))
}

/// [`output_latency`] as a check: the median and 95 % of the writes within the goal. The worst
/// is shown, not held: QEMU's guest shares this PC's cores, and a QEMU thread put aside by the
/// OS for a few ms is not the module's design.
pub(crate) async fn output_latency_check(addr: SocketAddr, model: &str, writes: u32) -> Result<(), String> {
    let (median, p95, worst) = output_latency(addr, writes).await?;
    println!(
        "qemu-{model}: DO write to the output pattern, {writes} writes: median {median} µs, 95 % {p95} µs, worst {worst} µs"
    );
    if median > OUTPUT_LATENCY_GOAL_US || p95 > OUTPUT_LATENCY_GOAL_US {
        return Err(format!("median {median} µs, 95 % {p95} µs: above {OUTPUT_LATENCY_GOAL_US} µs"));
    }
    Ok(())
}
