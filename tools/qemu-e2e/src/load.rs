//! Modbus during a web load (issue #25): the measure in alternating blocks, its figures, and
//! the watch on QEMU's log for the machine's stalls.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use tokio::time::{sleep, timeout};

use crate::client::STEP;
use crate::modbus::{burst, median};
use crate::stalls::{stalls_and_underruns, Stall};

/// The web load's clients stand for browsers on other PCs of the LAN: on this PC they run at
/// the lowest priority (nice 19, this thread only), so that they take no core from QEMU while
/// it has work (which on a 2-core machine would measure this PC's scheduler rather than the
/// firmware). They still get every cycle left idle.
fn like_another_machine() {
    // SAFETY: gettid and setpriority take no pointers; they change this thread's nice only.
    unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        libc::setpriority(libc::PRIO_PROCESS, tid, 19);
    }
}

/// Issue #25: the Modbus request latency alone and while two clients reload the live data
/// (`/api/v1/di` and `/api/v1/diagnostics`, then `/api/v1/do`, one connection a request, as
/// fast as they are answered) and a third trickles a request a byte every 200 ms (held until
/// the module's 3 s request timeout, then again).
///
/// The two measures are taken in [`WEB_LOAD_BLOCKS`] alternating blocks of 100 requests (the
/// load paused, then running), so that both see this PC and its hypervisor over the same
/// seconds. The load's clients stand for browsers on other PCs and run at the lowest priority
/// here ([`like_another_machine`]).
///
/// One measure, never taken again (a firmware over the bound one run in two would pass a
/// second chance three times in four), so its figures must not be this PC's:
/// - the median of the 2000 requests under the load within 2x the median of the 2000 alone;
/// - their 95th percentile within 4x alone's.
///
/// The worst, the figure, is this PC's under QEMU: a QEMU thread put aside for a few
/// ms makes a worst case of its own in either measure (worsts of 1000 from 1.1 to 24 ms with no
/// load at all). Over 45 runs here (December 2026, 2 cores shared with other work) the
/// firmware of today gave, loaded over alone: medians 1.1x to 1.75x; 95th percentiles 1.1x to
/// 3.0x; each block's worst (their median) 1.5x to 3.7x. A web answer is rendered in one poll
/// of the executor Modbus shares (about 0.3 ms under QEMU), and the load's clients and QEMU's
/// user network take this PC's cores from QEMU: a tail or a worst held at 2x would fail a
/// firmware as good as today's one run in two, so the tail's bound is 4x and the median's the
/// issue's 2x. A web part that delays Modbus (a long poll, a lock held across a slow client,
/// interrupts masked) delays each Modbus request that meets it: the 95th percentile moves as
/// soon as one in 20 does (10 ms masked at each web request gave 40x), the median once most
/// do. The worsts (overall and each block's) are printed.
///
/// A request during which the emulated machine stalled (QEMU's log, `log`, gained a "machine
/// stalled" line of the QEMU board: no SysTick for over 5 ms) counts with the time no critical
/// section of the firmware held taken off ([`Stall::lost`]): that part measures this PC. How
/// many were so is reported.
///
/// The load must run through each loaded block: before it, [`WEB_LEAD_ANSWERS`] new web
/// answers are waited for (5 s at most), and during it one more at least. A web server that
/// answered once and then hung fails at the next block.
pub(crate) async fn modbus_during_web_load(modbus: SocketAddr, web: SocketAddr, log: &str) -> Result<(), String> {
    use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
    use std::sync::Arc;
    const PER_BLOCK: usize = 100;
    let (stop, paused) = (Arc::new(AtomicBool::new(false)), Arc::new(AtomicBool::new(true)));
    // Web answers served, and web requests under way (none while Modbus is measured alone:
    // the measure waits for them to end).
    let (served, busy) = (Arc::new(AtomicU32::new(0)), Arc::new(AtomicU32::new(0)));
    let mut load = Vec::new();
    for target in ["/api/v1/di", "/api/v1/diagnostics"] {
        let (stop, paused, served, busy) = (stop.clone(), paused.clone(), served.clone(), busy.clone());
        load.push(std::thread::spawn(move || {
            like_another_machine();
            while !stop.load(Ordering::Relaxed) {
                for t in [target, "/api/v1/do"] {
                    busy.fetch_add(1, Ordering::SeqCst);
                    if paused.load(Ordering::SeqCst) {
                        busy.fetch_sub(1, Ordering::SeqCst);
                        std::thread::sleep(Duration::from_millis(1));
                        break;
                    }
                    if remodaq_board_host::testing::web::request(web, "GET", t, &[], "").status == 200 {
                        served.fetch_add(1, Ordering::Relaxed);
                    }
                    busy.fetch_sub(1, Ordering::SeqCst);
                }
            }
        }));
    }
    let (trickle_stop, trickle_paused) = (stop.clone(), paused.clone());
    load.push(std::thread::spawn(move || {
        use std::io::Write;
        like_another_machine();
        let text = b"GET /api/v1/identity HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ";
        while !trickle_stop.load(Ordering::Relaxed) {
            if trickle_paused.load(Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(1));
                continue;
            }
            let Ok(mut s) = std::net::TcpStream::connect(web) else { continue };
            for byte in text.iter().chain(std::iter::repeat(&b'x')) {
                if trickle_stop.load(Ordering::Relaxed) {
                    break;
                }
                if !trickle_paused.load(Ordering::Relaxed) && s.write_all(&[*byte]).is_err() {
                    break;
                }
                std::thread::sleep(Duration::from_millis(200));
            }
        }
    }));
    let measured = async {
        let mut stream =
            timeout(STEP, tokio::net::TcpStream::connect(modbus)).await.map_err(|_| "connect")?.map_err(|e| e.to_string())?;
        let _ = stream.set_nodelay(true);
        let mut blocks = Vec::new();
        let mut stalls = StallWatch::new(log);
        for block in 0..WEB_LOAD_BLOCKS {
            let (mut alone, mut loaded) = (Latencies::default(), Latencies::default());
            paused.store(true, Ordering::SeqCst);
            // The web requests under way end before the block alone starts.
            let quiet = Instant::now();
            while busy.load(Ordering::SeqCst) != 0 {
                if quiet.elapsed() > STEP {
                    return Err(format!("block {block}: web requests still under way {STEP:?} after the load paused"));
                }
                sleep(Duration::from_millis(1)).await;
            }
            sleep(Duration::from_millis(5)).await;
            stalls.since();
            for _ in 0..PER_BLOCK {
                let took = burst(&mut stream, 1).await?;
                alone.add(took, stalls.since());
            }
            let unpaused = served.load(Ordering::SeqCst);
            paused.store(false, Ordering::SeqCst);
            // The load runs: new answers come.
            let lead = Instant::now();
            while served.load(Ordering::SeqCst) - unpaused < WEB_LEAD_ANSWERS {
                if lead.elapsed() > STEP {
                    let answers = served.load(Ordering::SeqCst) - unpaused;
                    return Err(format!(
                        "block {block}: {answers} web answers within {STEP:?} of the load's start ({WEB_LEAD_ANSWERS} wanted): the web load is not served"
                    ));
                }
                sleep(Duration::from_millis(1)).await;
            }
            stalls.since();
            let served_before = served.load(Ordering::SeqCst);
            for _ in 0..PER_BLOCK {
                let took = burst(&mut stream, 1).await?;
                loaded.add(took, stalls.since());
            }
            let answers = served.load(Ordering::SeqCst) - served_before;
            if answers == 0 {
                return Err(format!(
                    "block {block}: no web answer while Modbus made {PER_BLOCK} requests under the load: the web load stopped"
                ));
            }
            blocks.push(Block { alone, loaded, answers });
        }
        Ok::<_, String>(blocks)
    }
    .await;
    stop.store(true, Ordering::Relaxed);
    for t in load {
        let _ = tokio::task::spawn_blocking(move || t.join()).await;
    }
    let blocks = measured?;
    let verdict = WebLoad::of(&blocks);
    println!("  {verdict}");
    let ms = |l: &Latencies| format!("{:.1}", l.worst().as_secs_f64() * 1e3);
    println!(
        "  each block's worst, ms: alone [{}], loaded [{}]; web answers [{}]",
        blocks.iter().map(|b| ms(&b.alone)).collect::<Vec<_>>().join(" "),
        blocks.iter().map(|b| ms(&b.loaded)).collect::<Vec<_>>().join(" "),
        blocks.iter().map(|b| b.answers.to_string()).collect::<Vec<_>>().join(" ")
    );
    let (alone, loaded) = (verdict.alone.median(), verdict.loaded.median());
    if loaded > alone * 2 {
        return Err(format!("the median during the web load, {loaded:?}, is over 2x the median alone, {alone:?}"));
    }
    let (alone, loaded) = (verdict.alone.quantile(95), verdict.loaded.quantile(95));
    if loaded > alone * 4 {
        return Err(format!("95 % during the web load within {loaded:?}, over 4x alone's {alone:?}"));
    }
    Ok(())
}

/// Alternating blocks of the web-load measure.
const WEB_LOAD_BLOCKS: usize = 20;

/// New web answers waited for before each loaded block (it lasts about 30 ms, and sees 3 to
/// 20 answers here).
const WEB_LEAD_ANSWERS: u32 = 2;

/// One block pair of the web-load measure: Modbus alone, then under the load, and the web
/// answers served meanwhile.
struct Block {
    alone: Latencies,
    loaded: Latencies,
    answers: u32,
}

/// The web-load measure's figures.
struct WebLoad {
    /// The median over blocks of each block's worst, alone and loaded.
    alone_block_worst: Duration,
    loaded_block_worst: Duration,
    alone: Latencies,
    loaded: Latencies,
    answers: u32,
    fewest_answers: u32,
}

impl WebLoad {
    fn of(blocks: &[Block]) -> Self {
        let worsts = |f: fn(&Block) -> &Latencies| median(blocks.iter().map(|b| f(b).worst()).collect());
        let all = |f: fn(&Block) -> &Latencies| Latencies {
            took: blocks.iter().flat_map(|b| f(b).took.iter().copied()).collect(),
            stalled: blocks.iter().map(|b| f(b).stalled).sum(),
            guest: None,
        };
        Self {
            alone_block_worst: worsts(|b| &b.alone),
            loaded_block_worst: worsts(|b| &b.loaded),
            alone: all(|b| &b.alone),
            loaded: all(|b| &b.loaded),
            answers: blocks.iter().map(|b| b.answers).sum(),
            fewest_answers: blocks.iter().map(|b| b.answers).min().unwrap_or(0),
        }
    }
}

impl std::fmt::Display for WebLoad {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (a, l) = (&self.alone, &self.loaded);
        write!(
            f,
            "Modbus alone: median {:?}, 95 % {:?}, 99 % {:?}, worst {:?}, blocks' median worst {:?} ({} requests during a stall of the machine, the time no critical section held taken off); during the web load ({} web answers, {} in the fewest block): median {:?}, 95 % {:?}, 99 % {:?}, worst {:?}, blocks' median worst {:?} ({} during a stall)",
            a.median(),
            a.quantile(95),
            a.quantile(99),
            a.worst(),
            self.alone_block_worst,
            a.stalled,
            self.answers,
            self.fewest_answers,
            l.median(),
            l.quantile(95),
            l.quantile(99),
            l.worst(),
            self.loaded_block_worst,
            l.stalled
        )
    }
}

/// Request latencies, each less the time the machine stalled during it; and how many were so.
#[derive(Default)]
pub(crate) struct Latencies {
    took: Vec<Duration>,
    pub(crate) stalled: usize,
    /// The guest's own measure of the same requests, when it gave one (`crate::guest`).
    pub(crate) guest: Option<crate::guest::Guest>,
}

impl Latencies {
    pub(crate) fn add(&mut self, took: Duration, lost: Duration) {
        if !lost.is_zero() {
            self.stalled += 1;
        }
        self.took.push(took.saturating_sub(lost));
    }

    pub(crate) fn worst(&self) -> Duration {
        self.took.iter().copied().max().unwrap_or_default()
    }

    pub(crate) fn median(&self) -> Duration {
        self.quantile(50)
    }

    /// The `percent` quantile (the lower one where it falls between two).
    pub(crate) fn quantile(&self, percent: usize) -> Duration {
        let mut took = self.took.clone();
        took.sort();
        took.get((took.len() * percent / 100).min(took.len().saturating_sub(1))).copied().unwrap_or_default()
    }
}

/// Watches QEMU's log for the QEMU board's "machine stalled" lines.
pub(crate) struct StallWatch<'a> {
    log: &'a str,
    read: u64,
}

impl<'a> StallWatch<'a> {
    pub(crate) fn new(log: &'a str) -> Self {
        let read = std::fs::metadata(log).map_or(0, |m| m.len());
        Self { log, read }
    }

    /// The time this PC took from the machine in the stalls the log said since the last call:
    /// each gap between two SysTicks less the 1 ms period and the firmware's critical sections
    /// ([`Stall::lost`]).
    pub(crate) fn since(&mut self) -> Duration {
        use std::io::{Read, Seek, SeekFrom};
        let Ok(mut file) = std::fs::File::open(self.log) else { return Duration::ZERO };
        let mut added = Vec::new();
        if file.seek(SeekFrom::Start(self.read)).is_err() || file.read_to_end(&mut added).is_err() {
            return Duration::ZERO;
        }
        self.read += added.len() as u64;
        let (stalls, _) = stalls_and_underruns(&String::from_utf8_lossy(&added));
        Duration::from_micros(stalls.iter().map(Stall::lost).sum())
    }
}
