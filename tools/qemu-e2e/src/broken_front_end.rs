//! The 8318's update check with a broken front end (issue #21): an update that never confirms
//! is reverted, the reverted image runs no trial of its own, and a further update is accepted.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use remodaq_protocol::diag;
use tokio::time::sleep;

use crate::client::{connect, regs_until, uptime, wait_ready};
use crate::discovery::{set_password, PASSWORD};
use crate::qemu::{start_qemu_with, Ports, FRONT_END_FAULT, TRIAL_S};
use crate::report::Report;
use crate::session::{reverted, session};

/// How long the 8318 with a broken front end is watched after the revert (issue #21): three
/// trial windows, and a little more. What the watch must show is that the reverted image does
/// not run a trial of its own (the endless trial of issue #21: on trial, its self-test failing
/// as the front end does, it would restart a trial after each start, and the bootloader would
/// start it again). Such a loop restarts once every trial window, whenever it began: its first
/// restart falls within the first window after the revert, and the uptime goes back. Three
/// windows see that restart three times over, and a loop that restarted only every second or
/// third start (a trial that passed by chance some times) at least once; longer adds nothing
/// a trial's timer could do. The watch was 180 s before (issue #36).
const NO_RESTART_FOR: Duration = Duration::from_secs(3 * TRIAL_WINDOW_S + 2);
/// A trial window under QEMU, s: an image on trial restarts a trial after its start when its
/// self-test has not passed, and starts again within about 1 s.
const TRIAL_WINDOW_S: u64 = TRIAL_S + 1;
/// The watch polls the uptime this often.
const WATCH_POLL: Duration = Duration::from_secs(3);

/// Issue #21 (the endless trial): an 8318 whose front end fails on every channel (the board's
/// test switch, which every image started on this machine sees, as a broken AD7124-8 would)
/// takes an update (A101) that never confirms, because its self-test fails the same way. After
/// its trial the module restarts and the bootloader reverts to A100, which it started in
/// the Revert state: A100 is confirmed without a trial, so it does not restart again. Watched
/// for three trial windows ([`NO_RESTART_FOR`]: uptime never goes back, restarts counted, 0
/// wanted); then a further update is accepted (the answer to a whole session is "verified and
/// marked").
pub(crate) async fn broken_front_end(report: &mut Report, image: &str) {
    const REVERTED: &str = "update: an 8318 whose front end fails takes an update that never confirms; after the revert, no restart through 3 trial windows (35 s)";
    const FURTHER: &str = "update: after that revert a further update is accepted";
    let v2 = match std::fs::read(format!("{image}-v2.rdq")) {
        Ok(file) => file,
        Err(e) => {
            report.check(REVERTED, Err(format!("{image}-v2.rdq: {e}: run scripts/qemu variants")));
            return;
        }
    };
    let Ok(ports) = Ports::free() else {
        report.check(REVERTED, Err("no free ports".into()));
        return;
    };
    let qemu = match start_qemu_with(image, &ports, Some(FRONT_END_FAULT), false) {
        Ok(q) => q,
        Err(e) => {
            report.check(REVERTED, Err(e));
            return;
        }
    };
    let (addr, update) = (ports.modbus(), SocketAddr::from(([127, 0, 0, 1], ports.update)));
    let discovery = SocketAddr::from(([127, 0, 0, 1], ports.udp));
    let reverted = async {
        let mut ctx = wait_ready(addr).await?;
        // The fault is seen: the front-end fault bit after the first cycles, outside the board's
        // own injected fault (20-23 s after the start).
        let status =
            regs_until(&mut ctx, diag::REG_MODULE_STATUS, 1, |v| v[0] & diag::status::FRONT_END_FAULT != 0).await?[0];
        let up = uptime(&mut ctx).await?;
        if status & diag::status::FRONT_END_FAULT == 0 || (19..=24).contains(&up) {
            return Err(format!("the test switch did not fail the front end: status {status:04x} at {up} s"));
        }
        drop(ctx);
        set_password(discovery).await?;
        let answers = session(update, PASSWORD, &v2, usize::MAX).await?;
        if answers != [0, 0] {
            return Err(format!("the update (A101): the module answered {answers:?}"));
        }
        let took = reverted(addr, 0xA101, 0xA100).await?;
        println!("qemu-8318: A101 ran on trial and was reverted to A100 after {:.1} s", took.as_secs_f64());
        // A100 now: count its restarts over three trial windows.
        let watched = Instant::now();
        let mut restarts = 0;
        let mut last = 0u32;
        let mut first = None;
        let mut polls = 0;
        while watched.elapsed() < NO_RESTART_FOR {
            let up = match connect(addr).await {
                Ok(mut ctx) => uptime(&mut ctx).await.ok(),
                Err(_) => None,
            };
            match up {
                Some(up) => {
                    if up < last {
                        restarts += 1;
                        println!("qemu-8318: restarted: uptime {up} s after {last} s");
                    }
                    last = up;
                    first.get_or_insert(up);
                    polls += 1;
                }
                None => println!("qemu-8318: no answer at {:.0} s of the watch", watched.elapsed().as_secs_f64()),
            }
            sleep(WATCH_POLL).await;
        }
        // Polled every 3 s: answers all along (at most two polls missed), and the last came at
        // least the watch less two polls (29 s, over two and a half trial windows) after the
        // first on the module's clock too (the QEMU board's follows the wall clock).
        let first = first.unwrap_or(u32::MAX);
        let least_polls = (NO_RESTART_FOR.as_secs() / WATCH_POLL.as_secs()) as u32 - 2;
        let least_span = (NO_RESTART_FOR - 2 * WATCH_POLL).as_secs() as u32;
        println!(
            "qemu-8318: watched A100 for {} s after the revert: {restarts} restarts, uptime {first} s then {last} s, {polls} polls",
            NO_RESTART_FOR.as_secs()
        );
        if restarts > 0 || polls < least_polls || last < first.saturating_add(least_span) {
            return Err(format!(
                "{restarts} restarts in {} s (uptime {first} s, then {last} s; {polls} answers)",
                NO_RESTART_FOR.as_secs()
            ));
        }
        Ok(())
    }
    .await;
    let ok = reverted.is_ok();
    report.check(REVERTED, reverted);
    let further = async {
        if !ok {
            return Err("not tried: the revert check failed".to_string());
        }
        match session(update, PASSWORD, &v2, usize::MAX).await? {
            a if a == [0, 0] => Ok(()),
            a => Err(format!("the module answered {a:?}, expected [0, 0] (verified and marked)")),
        }
    };
    report.check(FURTHER, further.await);
    drop(qemu);
}
