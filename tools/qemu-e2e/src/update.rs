//! The 8350's update checks (issues #12 and #21): refusals, `remodaq update`, a rollback, a
//! revert, a forged swap, and the module's inputs and outputs during a whole session.

use std::net::SocketAddr;
use std::process::Command;
use std::time::{Duration, Instant};

use remodaq_protocol::diag;
use remodaq_protocol::discovery::{decode_info, encode_request, Request, Status, MAX_DATAGRAM};
use remodaq_protocol::m8350::{Point, PulseField, Word};
use tokio::time::{sleep, timeout};
use tokio_modbus::client::{Context, Writer as _};

use crate::client::{connect, diag_reg, regs, uptime, write, STEP};
use crate::discovery::{discover, set_password, PASSWORD};
use crate::qemu::TRIAL_S;
use crate::report::Report;
use crate::session::{paced_session, reverted, session, version};
use crate::stalls::{longest_critical_section, stalls_and_underruns, unexplained_underruns, Stall};

/// Issue #12 through the emulated NIC: a bad signature and a truncated image are refused with
/// nothing changed; `remodaq update` takes v1 to v2 (A101), which answers after the reset; a
/// v3 (A102) that never confirms itself is reverted to v2 after its trial's reset; the
/// setting written before (DO0's pulse low width, `setting written and read back`) is intact
/// after every step.
pub(crate) async fn updates(
    report: &mut Report,
    image: &str,
    addr: SocketAddr,
    update: SocketAddr,
    discovery: SocketAddr,
) {
    let pulse_low = Point::Pulse(PulseField::Low, 0, Word::Low).addr().1;
    let setting_intact = async |when: &str| -> Result<(), String> {
        let mut ctx = connect(addr).await?;
        match regs(&mut ctx, pulse_low, 2).await? {
            v if v == [25, 0] => Ok(()),
            v => Err(format!("{when}: DO0's pulse low width reads {v:?}, written [25, 0]")),
        }
    };
    let read = |name: &str| std::fs::read(format!("{image}-{name}.rdq"));
    let (Ok(v2), Ok(v3), Ok(v4), Ok(v5), Ok(old), Ok(other)) =
        (read("v2"), read("v3"), read("v4"), read("v5"), read("old"), read("other"))
    else {
        report.check("update images", Err("the test images are missing: run scripts/qemu variants".into()));
        return;
    };
    // Updates are refused while the factory password is in force; then a password is set.
    let factory = session(update, "remodaq", &v2, usize::MAX).await;
    report.check(
        "update: refused while the factory password is in force (status 7), nothing changed",
        match factory {
            Ok(a) if a == [Status::SetPasswordFirst as u8] => Ok(()),
            other => Err(format!("answers {other:?}")),
        },
    );
    report
        .check("update: a password set over discovery (sealed credential)", set_password(discovery).await.map(|_| ()));
    let refused_at = async |running: u16, what: &str, file: &[u8], send: usize, want: &[u8]| -> Result<(), String> {
        let answers = session(update, PASSWORD, file, send).await?;
        if answers != want {
            return Err(format!("{what}: the module answered {answers:?}, expected {want:?}"));
        }
        match version(addr).await? {
            v if v == running => setting_intact(what).await,
            v => Err(format!("{what}: version {v:04X} afterwards, expected {running:04X} (nothing changed)")),
        }
    };
    let refused =
        async |what: &str, file: &[u8], send: usize, want: &[u8]| refused_at(0xA100, what, file, send, want).await;
    let mut tampered = v2.clone();
    let last = tampered.len() - 1;
    tampered[last] ^= 0x01;
    report.check(
        "update: a bad signature is refused, nothing changed",
        refused("bad signature", &tampered, usize::MAX, &[0, 5]).await,
    );
    report.check(
        "update: a truncated image is refused, nothing changed",
        refused("truncated", &v2, v2.len() / 2, &[0]).await,
    );
    report.check(
        "update: the other model's image is refused (status 3), nothing changed",
        refused("the 8318's image", &other, usize::MAX, &[3]).await,
    );

    // The module's clock is QEMU's, which follows the wall clock: when this machine keeps QEMU
    // from running for longer than the output ring's slack (6.4 ms), the guest finds its ring
    // run dry, as a module would whose CPU stopped. The QEMU board says each such stall, how
    // much of it the firmware's critical sections held, and each underrun in its log; an
    // underrun right after a stall no critical section covered is this PC's, any other the
    // firmware's (a task that kept the I/O loop waiting, or interrupts masked). One session,
    // never taken again: a firmware that failed one session in two would pass a second chance
    // three times in four.
    let log = format!("{image}.qemu.log");
    report.check(
        "update: during a whole session, DI0's 1 kHz counter loses no edge, the outputs never run dry (unless this PC stalled the machine outside the firmware's critical sections), settings writes answer within 1 s",
        during_update(addr, update, &tampered, &log).await,
    );

    // The tool with the MAC of another module (security review finding 15a): refused before
    // any proof is sent, nothing changed.
    let remodaq = || Command::new(std::env::var("REMODAQ").unwrap_or_else(|_| "target/debug/remodaq".into()));
    let mut buf = [0u8; MAX_DATAGRAM];
    let n = encode_request(12, &Request::Search, &mut buf).unwrap_or(0);
    let mac = discover(discovery, &buf[..n]).await.ok().and_then(|reply| decode_info(&reply).map(|i| i.mac));
    let mac_text = |m: [u8; 6]| m.iter().map(|b| format!("{b:02x}")).collect::<Vec<_>>().join(":");
    let other_mac = async {
        let Some(mac) = mac else { return Err("no search answer: the module's MAC is unknown".to_string()) };
        let other = [mac[0], mac[1], mac[2], mac[3], mac[4], mac[5] ^ 0x01];
        let out = remodaq()
            .args(["update", &addr.to_string(), &format!("{image}-v2.rdq"), "--mac", &mac_text(other)])
            .env("REMODAQ_PASSWORD", PASSWORD)
            .args(["--port", &update.port().to_string()])
            .output()
            .map_err(|e| format!("cannot run remodaq: {e}"))?;
        let said = String::from_utf8_lossy(&out.stderr).into_owned();
        if out.status.success() || !said.contains("nothing sent") {
            return Err(format!("remodaq update --mac {}: exit {:?}, {said:?}", mac_text(other), out.status.code()));
        }
        match version(addr).await? {
            0xA100 => setting_intact("after the other MAC").await,
            v => Err(format!("after the other MAC: version {v:04X}")),
        }
    };
    report.check(
        "update: the tool named another module's MAC: refused before any proof, nothing changed",
        other_mac.await,
    );

    // v1 -> v2 with the tool, naming the module's MAC.
    let started = Instant::now();
    let tool = remodaq()
        .args(["update", &addr.to_string(), &format!("{image}-v2.rdq")])
        .args(mac.map(|m| vec!["--mac".to_string(), mac_text(m)]).unwrap_or_default())
        .env("REMODAQ_PASSWORD", PASSWORD)
        .args(["--port", &update.port().to_string()])
        .output();
    let v1_to_v2 = match tool {
        Ok(out) if out.status.success() => {
            let text = String::from_utf8_lossy(&out.stdout).into_owned();
            print!("{text}");
            match (text.contains("A100 -> A101"), version(addr).await) {
                (true, Ok(0xA101)) => {
                    // A search shows the running version too.
                    let mut buf = [0u8; MAX_DATAGRAM];
                    let n = encode_request(11, &Request::Search, &mut buf).unwrap_or(0);
                    match discover(discovery, &buf[..n]).await.map(|reply| decode_info(&reply).map(|i| i.version)) {
                        Ok(Some(0xA101)) => setting_intact("after v2").await,
                        other => Err(format!("a search after the update: version {other:?}")),
                    }
                }
                (_, v) => Err(format!("after the update: {text:?}, version {v:?}")),
            }
        }
        Ok(out) => Err(format!("remodaq update failed: {}", String::from_utf8_lossy(&out.stderr))),
        Err(e) => Err(format!("cannot run remodaq: {e}")),
    };
    println!("qemu-8350: v1 -> v2 in {:.1} s", started.elapsed().as_secs_f64());
    report.check("update: v1 -> v2 through the emulated NIC, v2 answers (Modbus, search) after the reset", v1_to_v2);
    report.check(
        "update: after v2 (counter 2), A101 with counter 1 (v2 relabelled) is refused (status 8), nothing changed",
        refused_at(0xA101, "an older counter", &old, usize::MAX, &[8]).await,
    );

    // v3 never confirms: it runs on trial, then the reset reverts to v2.
    let rollback = async {
        let answers = session(update, PASSWORD, &v3, usize::MAX).await?;
        if answers != [0, 0] {
            return Err(format!("v3: the module answered {answers:?}"));
        }
        let took = reverted(addr, 0xA102, 0xA101).await?;
        println!("qemu-8350: v3 ran on trial and was reverted to v2 after {:.1} s", took.as_secs_f64());
        setting_intact("after the rollback").await
    };
    report.check("update: a v3 that never confirms rolls back to v2 after its reset", rollback.await);

    // v5's link never comes up: its self-test cannot pass, and after its trial the bootloader
    // reverts to v2. (Before v4: reverted to, v4 would forge its swap again and restart once
    // more, since the update partition would no longer hold its junk.)
    let link_down = async {
        let answers = session(update, PASSWORD, &v5, usize::MAX).await?;
        if answers != [0, 0] {
            return Err(format!("v5: the module answered {answers:?}"));
        }
        let marked = Instant::now();
        let mut seen = Vec::new();
        loop {
            let v = version(addr).await?;
            if seen.last() != Some(&v) {
                seen.push(v);
            }
            if v == 0xA101 && (seen.contains(&0xA104) || marked.elapsed() > Duration::from_secs(15)) {
                break;
            }
            if marked.elapsed() > Duration::from_secs(90) {
                return Err(format!("v2 did not answer again within 90 s (versions seen: {seen:04X?})"));
            }
            sleep(Duration::from_millis(500)).await;
        }
        // v2 again: it started at least a trial after v5 was marked (v5 ran its trial and was
        // reverted), after a software restart.
        let mut ctx = connect(addr).await?;
        let (up, cause) = (uptime(&mut ctx).await?, diag_reg(&mut ctx, diag::Diag::ResetCause).await?);
        let before_v2 = marked.elapsed().as_secs_f64() - f64::from(up);
        println!(
            "qemu-8350: v5 (link down) reverted to v2: v2 started {before_v2:.1} s after v5 was marked (versions seen {seen:04X?})"
        );
        if before_v2 < TRIAL_S as f64 - 1.0 || cause != diag::reset_cause::SOFTWARE {
            return Err(format!(
                "v2 started {before_v2:.1} s after v5 was marked, reset cause {cause}: expected after the {TRIAL_S} s trial, a software restart"
            ));
        }
        setting_intact("after the link-down revert").await
    };
    report.check("update: an image whose link never comes up fails its self-test and is reverted", link_down.await);

    // v4 confirms itself, then (as code that took the module over might) writes junk with a
    // forged manifest into the update partition, marks it and restarts: the bootloader refuses
    // the swap and v4 starts again.
    let forged = async {
        let answers = session(update, PASSWORD, &v4, usize::MAX).await?;
        if answers != [0, 0] {
            return Err(format!("v4: the module answered {answers:?}"));
        }
        let log = format!("{image}.qemu.log");
        let started = Instant::now();
        loop {
            let text = std::fs::read_to_string(&log).unwrap_or_default();
            let refused = text.contains("bootloader: the marked update is not signed with the key, or not for this model and counter: not swapped");
            if refused {
                if let Ok(0xA103) = version(addr).await {
                    println!(
                        "qemu-8350: the bootloader refused the forged swap; v4 answers again after {:.1} s",
                        started.elapsed().as_secs_f64()
                    );
                    break;
                }
            }
            if started.elapsed() > Duration::from_secs(120) {
                return Err(format!("no refusal by the bootloader within 120 s (refused: {refused})"));
            }
            sleep(Duration::from_secs(1)).await;
        }
        setting_intact("after the forged swap").await
    };
    report
        .check("update: junk marked in the update partition without a valid signature is not swapped in", forged.await);
}

/// What [`during_update`] says of an underrun, and of an overrun.
const RAN_DRY: &str = "the output pattern ran dry";
const OVERRAN: &str = "the capture ring overran";

/// Issue #21, the 8350 during an update: a whole session (the erase of each sector written, the
/// writes, the hash; the image's signature is bad, so it is refused at the very end and the
/// module does not restart) while DI0's 1 kHz square wave is counted, the outputs' pattern
/// plays, and a setting (DO0's pulse low width, persisted) is written every second. Counted
/// edges are bracketed by the two counter reads' send and answer times; the capture ring's
/// overrun bit (40241 bit 0, cleared by reading it), the pattern's underrun counter (40325)
/// and every write's answer time are checked.
async fn during_update(addr: SocketAddr, update: SocketAddr, file: &[u8], log: &str) -> Result<(), String> {
    let mut ctx = connect(addr).await?;
    // The QEMU board's injected sample loss (20-23 s after the start) must be over.
    while uptime(&mut ctx).await? < 24 {
        sleep(Duration::from_millis(500)).await;
    }
    diag_reg(&mut ctx, diag::Diag::Status).await?;
    let underruns = diag_reg(&mut ctx, diag::Diag::PatternUnderruns).await?;
    let log_from = std::fs::metadata(log).map_or(0, |m| m.len() as usize);
    write(&mut ctx, Point::DiMode(0).addr().1, &[1]).await?;
    let coil = |p: Point| p.addr().1;
    timeout(STEP, ctx.write_single_coil(coil(Point::CounterClear(0)), true))
        .await
        .map_err(|_| "no answer".to_string())?
        .map_err(|e| e.to_string())?
        .map_err(|e| format!("exception {e:?}"))?;
    timeout(STEP, ctx.write_single_coil(coil(Point::CounterRun(0)), true))
        .await
        .map_err(|_| "no answer".to_string())?
        .map_err(|e| e.to_string())?
        .map_err(|e| format!("exception {e:?}"))?;
    let counter = Point::Counter(0, Word::Low).addr().1;
    let read_counter = async |ctx: &mut Context| -> Result<(u32, Instant, Instant), String> {
        let sent = Instant::now();
        let w = regs(ctx, counter, 2).await?;
        Ok((u32::from(w[0]) | u32::from(w[1]) << 16, sent, Instant::now()))
    };
    let (c0, sent0, answered0) = read_counter(&mut ctx).await?;
    let pulse_low = Point::Pulse(PulseField::Low, 0, Word::Low).addr().1;
    let mut writer = connect(addr).await?;
    let done = std::cell::Cell::new(false);
    let session = async {
        // About 5 s: 2 KiB every 60 ms (the flash of the QEMU board erases and writes at once).
        let pace = Some((2048, Duration::from_millis(60)));
        let answers = paced_session(update, PASSWORD, file, usize::MAX, pace).await;
        done.set(true);
        answers
    };
    // A write every second for as long as the session runs, alternating 26 and 25 (each a
    // commit: about 5 a session, within the commit budget of 20 with the run's other writes).
    let writes = async {
        let (mut slowest, mut n) = (Duration::ZERO, 0u32);
        while !done.get() {
            let sent = Instant::now();
            write(&mut writer, pulse_low, &[if n % 2 == 0 { 26 } else { 25 }, 0]).await?;
            slowest = slowest.max(sent.elapsed());
            n += 1;
            for _ in 0..10 {
                if done.get() {
                    break;
                }
                sleep(Duration::from_millis(100)).await;
            }
        }
        Ok::<(Duration, u32), String>((slowest, n))
    };
    let (answers, writes) = tokio::join!(session, writes);
    let session_took = sent0.elapsed();
    let (c1, sent1, answered1) = read_counter(&mut ctx).await?;
    if answers? != [0, Status::BadSignature as u8] {
        return Err("the session was not refused at the end for its bad signature".into());
    }
    let (slowest, writes_made) = writes.map_err(|e| format!("a settings write during the session: {e}"))?;
    write(&mut writer, pulse_low, &[25, 0]).await?;
    const LAG: u32 = 3;
    let counted = c1.wrapping_sub(c0);
    let least = (sent1.saturating_duration_since(answered0).as_secs_f64() * 1000.0).floor() as u32;
    let most = (answered1.duration_since(sent0).as_secs_f64() * 1000.0).ceil() as u32;
    let status = diag_reg(&mut ctx, diag::Diag::Status).await?;
    let underruns_after = diag_reg(&mut ctx, diag::Diag::PatternUnderruns).await?;
    write(&mut ctx, Point::DiMode(0).addr().1, &[0]).await?;
    println!(
        "qemu-8350: during a {:.1} s update session DI0 counted {counted} (bracket {least}..={most}), status {status:04x}, underruns {underruns} -> {underruns_after}; {writes_made} settings writes, the slowest answered in {:.0} ms",
        session_took.as_secs_f64(),
        slowest.as_secs_f64() * 1e3
    );
    if writes_made < 2 || slowest > Duration::from_secs(1) {
        return Err(format!(
            "{writes_made} settings writes during the session, the slowest answered in {slowest:?} (1 s at most)"
        ));
    }
    // The counter moves when the capture is drained, every 2 ms: each read may lag the wave by
    // up to 2 edges, and 1 more for where the edge falls.
    if !(least.saturating_sub(LAG)..=most + LAG).contains(&counted) {
        return Err(format!("DI0 counted {counted} edges, the 1 kHz wave gave {least}..={most} (± {LAG})"));
    }
    if status & diag::status::FRONT_END_FAULT != 0 {
        return Err(format!("input samples were lost ({OVERRAN})"));
    }
    let dry = underruns_after.wrapping_sub(underruns);
    let text = std::fs::read(log).map_err(|e| format!("{log}: {e}"))?;
    let text = String::from_utf8_lossy(text.get(log_from..).unwrap_or(&[])).into_owned();
    let (stalls, dry_at) = stalls_and_underruns(&text);
    println!(
        "qemu-8350: during the session QEMU's log said {} stalls of the machine over 5 ms ({} ms lost outside critical sections, {} ms inside), the longest critical section {} us",
        stalls.len(),
        stalls.iter().map(Stall::lost).sum::<u64>() / 1000,
        stalls.iter().map(|s| s.masked).sum::<u64>() / 1000,
        longest_critical_section(&text)
    );
    if dry != 0 {
        let unexplained = unexplained_underruns(&stalls, &dry_at);
        println!(
            "qemu-8350: during the session the output pattern ran dry {dry} times (QEMU's log: {} underruns, {unexplained} unexplained: less than 3.2 ms lost just before outside critical sections, or 3.2 ms in them)",
            dry_at.len(),
        );
        if dry_at.len() != usize::from(dry) || unexplained != 0 {
            return Err(format!(
                "{RAN_DRY} {dry} times, {unexplained} of them not after a stall of the machine, or after critical sections of the firmware long enough to cause it"
            ));
        }
    }
    Ok(())
}
