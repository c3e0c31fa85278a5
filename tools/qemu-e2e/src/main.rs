//! Boots a firmware image in QEMU (mps2-an386, LAN9118 on QEMU's user network with the Modbus
//! port forwarded to a local port) and checks it through tokio-modbus: identity registers, live
//! values, a setting written and read back, 8 clients at once, and discovery (search, network
//! settings, restart) through the forwarded UDP port. Every wait is bounded; QEMU is
//! killed by its PID at the end. Prints one `qemu-<model>: N passed, N failed` line.
//!
//! `qemu-e2e 8318 IMAGE` or `qemu-e2e 8350 IMAGE` (`scripts/qemu build` builds the images).

use std::net::{SocketAddr, TcpListener};
use std::process::{Child, Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

use remodaq_protocol::auth;
use remodaq_protocol::diag;
use remodaq_protocol::discovery::client::{transact, Ask};
use remodaq_protocol::discovery::{decode_info, encode_request, Request, Status, MAX_DATAGRAM};
use remodaq_protocol::identity::{FIRMWARE_VERSION, REG_NAME, REG_VERSION};
use remodaq_protocol::m8318::{REG_CJC, REG_INPUT_TYPE, REG_VALUE};
use remodaq_protocol::m8350::{
    wd_mode, Point, PulseField, Word, BIT_DO, REG_ALL_DI, REG_ALL_DO, REG_DI_MODE, REG_SAFE_VALUES, REG_WD_MODE,
    REG_WD_STATUS, REG_WD_TIMEOUT,
};
use remodaq_protocol::net::NetConfig;
use remodaq_protocol::update::{answer_message, auth_message, Greeting, GREETING_LEN, HEADER_LEN};
use tokio::time::{sleep, timeout};
use tokio_modbus::client::{tcp, Context, Reader, Writer as _};

const STEP: Duration = Duration::from_secs(5);
const BOOT: Duration = Duration::from_secs(90);

struct Qemu(Child);

impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Clients of the newcomer check's flood.
const FLOOD: usize = 64;

/// The local ports QEMU's user network forwards to the guest.
struct Ports {
    /// Modbus/TCP (8000).
    modbus: u16,
    /// Discovery (UDP 8300).
    udp: u16,
    /// The update service (TCP 8301).
    update: u16,
    /// The web console (TCP 80).
    web: u16,
    /// One more port to Modbus/TCP for each flood client. QEMU's user network (slirp) listens
    /// on a forwarded port with a backlog of 1: the host's kernel holds two connections it has
    /// not accepted yet and drops the SYNs beyond, which the client sends again only 1 s later.
    /// Through one port, a flood reaches the guest spread over seconds, and a newcomer behind
    /// it waits 1 s for QEMU, not for the module. One port each puts the flood on the guest's
    /// wire at once, as 64 clients on a LAN would.
    flood: Vec<u16>,
}

/// Ports are chosen from a range of this many, one range per run (see [`port_range`]).
const PORT_RANGE: u16 = 4000;
/// The next port of this run's range to try (an offset in it).
static NEXT_PORT: std::sync::atomic::AtomicU16 = std::sync::atomic::AtomicU16::new(0);
/// The first port of this run's range.
static PORT_BASE: std::sync::atomic::AtomicU16 = std::sync::atomic::AtomicU16::new(28_000);

/// Chooses this run's port range from what it runs: each model its own, below Linux's ephemeral
/// ports (32768-60999). The test command runs both models at once: ports chosen by asking the
/// kernel for free ones (port 0) and released until QEMU binds them could be handed to the
/// other run meanwhile, for its QEMU or a client connection.
fn port_range(what: &str) {
    let base = match what {
        "8318" => 20_000,
        "8350" => 24_000,
        _ => 28_000,
    };
    PORT_BASE.store(base, std::sync::atomic::Ordering::Relaxed);
}

/// The next port of this run's range that is free now on the loopback (TCP, or UDP), never
/// one this run chose before (until the range wraps).
fn free_port(udp: bool) -> Result<u16, String> {
    use std::sync::atomic::Ordering::Relaxed;
    for _ in 0..PORT_RANGE {
        let port = PORT_BASE.load(Relaxed) + NEXT_PORT.fetch_add(1, Relaxed) % PORT_RANGE;
        let free = if udp {
            std::net::UdpSocket::bind(("127.0.0.1", port)).is_ok()
        } else {
            TcpListener::bind(("127.0.0.1", port)).is_ok()
        };
        if free {
            return Ok(port);
        }
    }
    Err("no free local port in this run's range".into())
}

impl Ports {
    /// Free local ports for all of them, from this run's range.
    fn free() -> Result<Self, String> {
        let udp = free_port(true)?;
        let tcp = (0..FLOOD + 3).map(|_| free_port(false)).collect::<Result<Vec<_>, _>>()?;
        Ok(Self { modbus: tcp[0], udp, update: tcp[1], web: tcp[2], flood: tcp[3..].to_vec() })
    }

    fn modbus(&self) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], self.modbus))
    }

    /// QEMU's user network with these forwards.
    fn nic(&self) -> String {
        let mut nic = format!(
            "user,id=nic0,model=lan9118,hostfwd=tcp:127.0.0.1:{}-:8000,hostfwd=udp:127.0.0.1:{}-:8300,hostfwd=tcp:127.0.0.1:{}-:8301,hostfwd=tcp:127.0.0.1:{}-:80",
            self.modbus, self.udp, self.update, self.web
        );
        for port in &self.flood {
            nic += &format!(",hostfwd=tcp:127.0.0.1:{port}-:8000");
        }
        nic
    }
}

/// QEMU started as the module starts: the board's bootloader (next to the image) as QEMU's
/// image, the application's raw binary (`IMAGE.bin`, from scripts/qemu build) as its seed.
fn start_qemu(image: &str, ports: &Ports) -> Result<Qemu, String> {
    start_qemu_with(image, ports, None)
}

/// The QEMU board's test switches word (boards/qemu/layout.x) and its front-end fault value
/// (boards/qemu/src/lib.rs, `test_switches`): "FEND".
const TEST_SWITCHES_ADDR: u32 = 0x003F_F000;
const FRONT_END_FAULT: u32 = 0x4645_4E44;

/// [`start_qemu`], with the board's test switches word set to `switches` at every reset
/// (a hardware fault every image on this machine sees).
fn start_qemu_with(image: &str, ports: &Ports, switches: Option<u32>) -> Result<Qemu, String> {
    let log = std::fs::File::create(format!("{image}.qemu.log")).map_err(|e| e.to_string())?;
    let bootloader = std::path::Path::new(image).with_file_name("remodaq-qemu-bootloader");
    // An image built before the board had a bootloader (for `latency` comparisons with older
    // builds) boots by itself.
    let boot: Vec<std::ffi::OsString> = if bootloader.exists() {
        let seed = format!("loader,file={image}.bin,addr=0x300000");
        vec!["-kernel".into(), bootloader.into(), "-device".into(), seed.into()]
    } else {
        vec!["-kernel".into(), image.into()]
    };
    // A packet capture of the emulated NIC, for diagnosis: REMODAQ_QEMU_PCAP=FILE.
    let capture = std::env::var("REMODAQ_QEMU_PCAP")
        .map_or(vec![], |file| vec!["-object".to_string(), format!("filter-dump,id=dump,netdev=nic0,file={file}")]);
    let child = Command::new("qemu-system-arm")
        .args(["-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "null"])
        .args(["-semihosting-config", "enable=on,target=native"])
        .args(["-nic", &ports.nic()])
        .args(capture)
        .args(boot)
        .args(switches.map_or(vec![], |word| {
            vec!["-device".to_string(), format!("loader,addr={TEST_SWITCHES_ADDR:#x},data={word:#x},data-len=4")]
        }))
        .stdin(Stdio::null())
        .stdout(log.try_clone().map_err(|e| e.to_string())?)
        .stderr(log)
        .spawn()
        .map_err(|e| format!("cannot start qemu-system-arm: {e}"))?;
    Ok(Qemu(child))
}

async fn connect(addr: SocketAddr) -> Result<Context, String> {
    timeout(STEP, tcp::connect(addr)).await.map_err(|_| "connect timed out".to_string())?.map_err(|e| e.to_string())
}

async fn regs(ctx: &mut Context, addr: u16, n: u16) -> Result<Vec<u16>, String> {
    let r = timeout(STEP, ctx.read_holding_registers(addr, n)).await.map_err(|_| "no answer in time".to_string())?;
    r.map_err(|e| e.to_string())?.map_err(|e| format!("exception {e:?}"))
}

async fn write(ctx: &mut Context, addr: u16, values: &[u16]) -> Result<(), String> {
    let r =
        timeout(STEP, ctx.write_multiple_registers(addr, values)).await.map_err(|_| "no answer in time".to_string())?;
    r.map_err(|e| e.to_string())?.map_err(|e| format!("exception {e:?}"))
}

/// Ready when the guest answers a request (QEMU accepts the TCP connection before the guest
/// listens, so only an exchange of data tells).
async fn wait_ready(addr: SocketAddr) -> Result<Context, String> {
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

struct Report {
    model: String,
    passed: u32,
    failed: u32,
}

/// How many checks a run of each model makes (`run` and `updates`): a run that stops early
/// (no boot, missing update images) counts every check it did not make as failed.
fn checks_of(model: u16) -> u32 {
    match model {
        0x8318 => 11,
        0x8350 => 25,
        _ => 0,
    }
}

impl Report {
    /// Counts every declared check that did not run as failed, and a run that made more
    /// checks than declared as one more failure (the declaration is out of date).
    fn finish(&mut self, declared: u32) {
        let made = self.passed + self.failed;
        if made < declared {
            println!("qemu-{}: {} checks not run, counted as failed", self.model, declared - made);
            self.failed += declared - made;
        } else if made > declared {
            self.check("the number of checks", Err(format!("{made} made, {declared} declared in checks_of")));
        }
    }

    fn check(&mut self, name: &str, result: Result<(), String>) {
        match result {
            Ok(()) => {
                self.passed += 1;
                println!("qemu-{} {name} ... ok", self.model);
            }
            Err(e) => {
                self.failed += 1;
                println!("qemu-{} {name} ... FAILED: {e}", self.model);
            }
        }
    }
}

/// Reads `n` registers from `addr` until `ok` accepts them (at most 3 s: a few acquisition
/// cycles after a setting changed).
async fn regs_until(ctx: &mut Context, addr: u16, n: u16, ok: impl Fn(&[u16]) -> bool) -> Result<Vec<u16>, String> {
    let deadline = Instant::now() + Duration::from_secs(3);
    loop {
        let v = regs(ctx, addr, n).await?;
        if ok(&v) || Instant::now() > deadline {
            return Ok(v);
        }
        sleep(Duration::from_millis(100)).await;
    }
}

/// |raw - expected| <= tolerance, else an error naming the channel.
fn near(what: &str, raw: u16, expected: f64, tolerance: f64) -> Result<(), String> {
    if (f64::from(raw) - expected).abs() <= tolerance {
        Ok(())
    } else {
        Err(format!("{what} reads {raw} ({raw:04x}), expected {expected:.1} ± {tolerance}"))
    }
}

/// The expected values come from the spec (§2.2 ranges, §2.3 scaling) and the NIST type K
/// table, for the QEMU board's simulated terminals (boards/qemu/src/analog.rs).
async fn live_values_8318(ctx: &mut Context) -> Result<(), String> {
    // Type K (factory, -250 .. 1400 °C): ch0 at 100 °C by the NIST table (4.096 mV, less the
    // cold junction's 1.000 mV at 25 °C): (100 + 250) / 1650 * 65535 = 13901.4; the table's
    // 3 decimals are worth 0.02 °C (one count): allow 2. 40009 = 25.00 °C; ch3 open = FFFFh.
    let v = regs(ctx, REG_VALUE, 9).await?;
    near("ch0 (type K, 100 °C)", v[0], 13901.4, 2.0)?;
    if v[REG_CJC as usize] != 2500 || v[3] != 0xFFFF {
        return Err(format!("40009 reads {:04x}, ch3 {:04x}: expected 09c4 and ffff", v[8], v[3]));
    }
    // ±50 mV (code 01): ch1 at 20 mV: (20 + 50) / 100 * 65535 = 45874.5.
    write(ctx, REG_INPUT_TYPE, &[0x01]).await?;
    let v = regs_until(ctx, REG_VALUE, 9, |v| v[3] != 0xFFFF).await?;
    near("ch1 (±50 mV, 20 mV)", v[1], 45874.5, 1.0)?;
    // ±20 mA (code 06): ch2 at 12 mA: (12 + 20) / 40 * 65535 = 52428.0.
    write(ctx, REG_INPUT_TYPE, &[0x06]).await?;
    let v = regs_until(ctx, REG_VALUE, 9, |v| v[2].abs_diff(52428) <= 1).await?;
    near("ch2 (±20 mA, 12 mA)", v[2], 52428.0, 1.0)?;
    // ±15 mV (code 00): ch4 ramps over 0 .. 10 mV, so reads within (0 + 15) / 30 * 65535 =
    // 32767.5 and (10 + 15) / 30 * 65535 = 54612.5, and moves.
    write(ctx, REG_INPUT_TYPE, &[0x00]).await?;
    let before = regs_until(ctx, REG_VALUE + 4, 1, |v| v[0] >= 32767).await?[0];
    sleep(Duration::from_millis(1500)).await;
    let after = regs(ctx, REG_VALUE + 4, 1).await?[0];
    for raw in [before, after] {
        if !(32767..=54613).contains(&raw) {
            return Err(format!("ch4 (0 .. 10 mV ramp on ±15 mV) reads {raw}, outside 32767 ..= 54613"));
        }
    }
    if after == before {
        return Err(format!("ch4 stayed at {before:04x}"));
    }
    write(ctx, REG_INPUT_TYPE, &[0x0F]).await
}

/// DI3 high, and DI0's 1 kHz square wave (boards/qemu/src/digital.rs) measured in frequency
/// mode: rising edges over the module's 1 s gate, which runs on the guest's clock, so exactly
/// 1000 Hz (± one edge for where the gate falls).
async fn live_values_8350(ctx: &mut Context) -> Result<(), String> {
    let di = regs(ctx, REG_ALL_DI, 1).await?[0];
    if di & 0b1000 == 0 {
        return Err(format!("all-DI register {di:04x}: DI3 should be high"));
    }
    write(ctx, REG_DI_MODE, &[4]).await?;
    sleep(Duration::from_millis(2500)).await;
    let hz = regs(ctx, Point::Counter(0, Word::Low).addr().1, 2).await?;
    if hz[0].abs_diff(1000) > 1 || hz[1] != 0 {
        return Err(format!("DI0 frequency reads {hz:?}, expected [1000, 0] (± 1 Hz)"));
    }
    write(ctx, REG_DI_MODE, &[0]).await
}

async fn live_values(model: u16, ctx: &mut Context) -> Result<(), String> {
    if model == 0x8318 {
        live_values_8318(ctx).await
    } else {
        live_values_8350(ctx).await
    }
}

async fn setting_round_trip(model: u16, ctx: &mut Context) -> Result<(), String> {
    let pulse_low = Point::Pulse(PulseField::Low, 0, Word::Low).addr().1;
    let (addr, values): (u16, &[u16]) = if model == 0x8318 { (REG_INPUT_TYPE, &[0x0E]) } else { (pulse_low, &[25, 0]) };
    write(ctx, addr, values).await?;
    let back = regs(ctx, addr, values.len() as u16).await?;
    if back != values {
        return Err(format!("wrote {values:x?} to {addr:#x}, read {back:x?}"));
    }
    Ok(())
}

/// Extensions §3 through the emulated NIC: a 0.5 s host watchdog fed by writes only, armed by
/// a write, trips (reads do not feed it): the DOs take their safe levels and a write to the
/// outputs answers exception 04; writing 0 to the status clears it. The timing comes from the
/// module's clock (SysTick under QEMU).
async fn host_watchdog(addr: SocketAddr) -> Result<Duration, String> {
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
async fn diagnostics(addr: SocketAddr) -> Result<(), String> {
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

/// A read of 40211 as raw bytes (transaction id `id`).
fn request(id: u16) -> [u8; 12] {
    let [t0, t1] = id.to_be_bytes();
    let [r0, r1] = REG_NAME.to_be_bytes();
    [t0, t1, 0, 0, 0, 6, 1, 3, r0, r1, 0, 1]
}

/// Sends `count` requests in one write and waits for all the answers (11 bytes each).
async fn burst(stream: &mut tokio::net::TcpStream, count: u16) -> Result<Duration, String> {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let requests: Vec<u8> = (0..count).flat_map(request).collect();
    let started = Instant::now();
    stream.write_all(&requests).await.map_err(|e| e.to_string())?;
    let mut answers = vec![0u8; 11 * usize::from(count)];
    timeout(STEP, stream.read_exact(&mut answers))
        .await
        .map_err(|_| "no answers in time".to_string())?
        .map_err(|e| e.to_string())?;
    let took = started.elapsed();
    for (i, answer) in answers.chunks(11).enumerate() {
        if answer[..2] != (i as u16).to_be_bytes() || answer[7] != 3 {
            return Err(format!("answer {i}: {answer:02x?}"));
        }
    }
    Ok(took)
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

/// One request at a time (median of 20), then 10 pipelined in one segment (median of 5):
/// the module answers every buffered request and flushes once, so the burst costs little
/// more than one request. Returns (single, burst).
async fn pipelining(addr: SocketAddr, limit: f64) -> Result<(Duration, Duration), String> {
    let mut stream =
        timeout(STEP, tokio::net::TcpStream::connect(addr)).await.map_err(|_| "connect")?.map_err(|e| e.to_string())?;
    let _ = stream.set_nodelay(true);
    let mut singles = Vec::new();
    for _ in 0..20 {
        singles.push(burst(&mut stream, 1).await?);
    }
    let mut bursts = Vec::new();
    for _ in 0..5 {
        bursts.push(burst(&mut stream, 10).await?);
    }
    let (single, ten) = (median(singles), median(bursts));
    println!(
        "  one request {single:?}, a pipelined burst of 10 {ten:?} ({:.1}x)",
        ten.as_secs_f64() / single.as_secs_f64()
    );
    if ten.as_secs_f64() > limit * single.as_secs_f64() {
        return Err(format!("a burst of 10 took {ten:?}, one request {single:?}"));
    }
    Ok((single, ten))
}

/// The newcomer's bound, relative to one request's time in the same run: the module may
/// answer the flood's 64 requests (and QEMU forward 64 handshakes) before the newcomer's, each
/// costing about one request, with a margin of 10 for the emulator's scheduling; not below
/// 300 ms (a fast single request says little of 64 handshakes through QEMU's user network:
/// about 65 ms seen), and never beyond 900 ms, so that a newcomer whose SYN was dropped (the
/// client sends it again after 1 s) always fails.
fn newcomer_limit(single: Duration) -> Duration {
    (single * (FLOOD as u32 + 1) * 10).clamp(Duration::from_millis(300), Duration::from_millis(900))
}

/// 64 clients connect at once, each through its own forwarded port, and each sends a request
/// (not waiting for its answer); right behind them a newcomer reads 40211. Spec: the newcomer
/// is answered, not reset (docs/modbus.md), and it does not wait beyond `limit`. A newcomer
/// the guest refused (QEMU then closes the connection) fails as "reset"; one answered late
/// fails as "waited".
async fn newcomer(ports: &Ports, model: u16, limit: Duration) -> Result<Duration, String> {
    let flood: Vec<_> = ports
        .flood
        .iter()
        .enumerate()
        .map(|(i, &port)| {
            tokio::spawn(async move {
                use tokio::io::AsyncWriteExt;
                let mut stream = tokio::net::TcpStream::connect(("127.0.0.1", port)).await?;
                stream.write_all(&request(i as u16)).await?;
                Ok::<_, std::io::Error>(stream)
            })
        })
        .collect();
    let mut open = Vec::new();
    for c in flood {
        if let Ok(Ok(stream)) = c.await {
            open.push(stream);
        }
    }
    let started = Instant::now();
    let answer = async {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut stream = timeout(STEP, tokio::net::TcpStream::connect(ports.modbus()))
            .await
            .map_err(|_| "connect timed out".to_string())?
            .map_err(|e| format!("connect: {e}"))?;
        stream.write_all(&request(0x4e43)).await.map_err(|e| format!("reset before the request was sent: {e}"))?;
        let mut answer = [0u8; 11];
        match timeout(STEP, stream.read_exact(&mut answer)).await {
            Err(_) => Err(format!("no answer within {STEP:?}")),
            Ok(Err(e)) => Err(format!("reset after {:?} without an answer: {e}", started.elapsed())),
            Ok(Ok(_)) => Ok(answer),
        }
    };
    let answer = answer.await.map_err(|e| format!("the newcomer was not answered: {e}"))?;
    let took = started.elapsed();
    println!("  newcomer answered after {took:?} (limit {limit:?}; {} flood connections open)", open.len());
    drop(open);
    if answer[..2] != [0x4e, 0x43] || answer[7..9] != [3, 2] || answer[9..11] != model.to_be_bytes() {
        return Err(format!("the newcomer's answer {answer:02x?}: not 40211 = {model:04x}"));
    }
    if took > limit {
        return Err(format!("the newcomer waited {took:?}, limit {limit:?}"));
    }
    Ok(took)
}

/// `qemu-e2e latency IMAGE...`: boots each image and reports its pipelining and newcomer
/// figures only (to compare two builds in one run). `qemu-e2e newcomer IMAGE RUNS`: boots the
/// image RUNS times, each time measuring one request, then the newcomer check; prints
/// `newcomer: N passed, N failed`.
async fn latency(image: &str) -> Result<(), String> {
    let ports = Ports::free()?;
    let addr = ports.modbus();
    let qemu = start_qemu(image, &ports)?;
    drop(wait_ready(addr).await?);
    println!("{image}:");
    let (single, _) = pipelining(addr, f64::INFINITY).await?;
    let model = if image.contains("8318") { 0x8318 } else { 0x8350 };
    let result = newcomer(&ports, model, newcomer_limit(single)).await;
    drop(qemu);
    result.map(|_| ())
}

/// One discovery request (UDP) and its reply, at most 3 tries of 2 s.
async fn discover(to: SocketAddr, request: &[u8]) -> Result<Vec<u8>, String> {
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
const PASSWORD: &str = "qemu-e2e password";

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
async fn discovery_and_restart(to: SocketAddr, modbus: SocketAddr, model: u16) -> Result<(), String> {
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

async fn eight_clients(addr: SocketAddr, model: u16) -> Result<(), String> {
    let mut tasks = Vec::new();
    for client in 0..8 {
        tasks.push(tokio::spawn(async move {
            let mut ctx = connect(addr).await?;
            for _ in 0..20 {
                let v = regs(&mut ctx, REG_NAME, 1).await?;
                if v != [model] {
                    return Err(format!("client {client}: {v:x?}"));
                }
            }
            Ok::<(), String>(())
        }));
    }
    for t in tasks {
        timeout(Duration::from_secs(60), t)
            .await
            .map_err(|_| "clients did not finish".to_string())?
            .map_err(|e| e.to_string())??;
    }
    Ok(())
}

async fn run(model: &str, image: &str) -> Report {
    let mut report = Report { model: model.to_string(), passed: 0, failed: 0 };
    let name = u16::from_str_radix(model, 16).unwrap_or(0);
    let ports = match Ports::free() {
        Ok(ports) => ports,
        Err(e) => {
            report.check("boot", Err(e));
            return report;
        }
    };
    let (addr, udp, update_port) = (ports.modbus(), ports.udp, ports.update);
    let qemu = match start_qemu(image, &ports) {
        Ok(q) => q,
        Err(e) => {
            report.check("boot", Err(e));
            return report;
        }
    };
    let mut ctx = match wait_ready(addr).await {
        Ok(ctx) => ctx,
        Err(e) => {
            report.check("boot", Err(e));
            return report;
        }
    };
    report.check("boot", Ok(()));
    let identity = async {
        let (n, v) = (regs(&mut ctx, REG_NAME, 1).await?, regs(&mut ctx, REG_VERSION, 1).await?);
        if n == [name] && v == [FIRMWARE_VERSION] {
            Ok(())
        } else {
            Err(format!("40211 read {n:04x?}, 40213 {v:04x?}"))
        }
    }
    .await;
    report.check("identity registers", identity);
    report.check("live values", live_values(name, &mut ctx).await);
    report.check("setting written and read back", setting_round_trip(name, &mut ctx).await);
    drop(ctx);
    report.check("8 clients at once", eight_clients(addr, name).await);
    let pipelined = pipelining(addr, 3.0).await;
    let single = pipelined.as_ref().map_or(Duration::from_millis(1), |(single, _)| *single);
    report.check("pipelined burst of 10 within 3x one request", pipelined.map(|_| ()));
    report.check(
        "newcomer answered, not reset, during a 64-connection flood (within 650x one request, 0.3-0.9 s)",
        newcomer(&ports, name, newcomer_limit(single)).await.map(|_| ()),
    );
    // The flood's last connections reach the guest (and are evicted or closed) for a while
    // after the newcomer's answer: let them drain before the next check.
    sleep(Duration::from_secs(3)).await;
    if name == 0x8350 {
        report.check(
            "DO write reaches the output pattern within 1 ms (median and 95 % of 200 writes, the module's own measure)",
            output_latency_check(addr, model, 200).await,
        );
        let watchdog = host_watchdog(addr).await;
        if let Ok(t) = &watchdog {
            println!(
                "qemu-{model}: host watchdog 0.5 s tripped {:.0} ms after the arming write",
                t.as_secs_f64() * 1e3
            );
        }
        report.check("host watchdog: trip to the safe levels, exception 04, clear", watchdog.map(|_| ()));
        // Before the web checks: the board injects its fault 20-23 s after the start, and the
        // web load's reads of /api/v1/diagnostics clear the 8350's bit as a Modbus read does;
        // a web load over those seconds left this check nothing to see.
        report.check("diagnostics: injected front-end fault, set and cleared", diagnostics(addr).await);
        let web = SocketAddr::from(([127, 0, 0, 1], ports.web));
        report.check(
            "web console: identity, a wrong then the right password, a signed DO write confirmed by Modbus, an unsigned one refused",
            web_console(web, addr).await,
        );
        report.check(
            "Modbus during a web load: the median of 2000 requests within 2x alone, 95 % within 4x (20 alternating blocks; 2 clients reloading, 1 trickling, web answers before and during each loaded block; the time this PC stalled the machine outside critical sections taken off; one attempt)",
            modbus_during_web_load(addr, web, &format!("{image}.qemu.log")).await,
        );
        report.check(
            "web console: 50 connections opened at once, at least 2 held by the module (open, and answered once completed), Modbus answering beside them, the console answering once they are gone",
            fifty_connections(web, addr).await,
        );
    }
    if name != 0x8350 {
        report.check("diagnostics: injected front-end fault, set and cleared", diagnostics(addr).await);
    }
    let discovery = SocketAddr::from(([127, 0, 0, 1], udp));
    report.check("discovery: search, network settings, restart", discovery_and_restart(discovery, addr, name).await);
    if name == 0x8350 {
        let update = SocketAddr::from(([127, 0, 0, 1], update_port));
        updates(&mut report, image, addr, update, discovery).await;
    }
    drop(qemu);
    if name == 0x8318 {
        broken_front_end(&mut report, image).await;
    }
    report
}

/// The web console under QEMU (issue #25, docs/web.md): identity read without a login; a
/// wrong password refused (401); the factory password logs in; DO5 switched on by a signed
/// request, which Modbus reads; an unsigned request refused with nothing changed; DO5 off
/// again.
async fn web_console(web: SocketAddr, modbus: SocketAddr) -> Result<(), String> {
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
async fn fifty_connections(web: SocketAddr, modbus: SocketAddr) -> Result<(), String> {
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
/// The worst, the issue's figure, is this PC's under QEMU: a QEMU thread put aside for a few
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
async fn modbus_during_web_load(modbus: SocketAddr, web: SocketAddr, log: &str) -> Result<(), String> {
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
struct Latencies {
    took: Vec<Duration>,
    stalled: usize,
}

impl Latencies {
    fn add(&mut self, took: Duration, lost: Duration) {
        if !lost.is_zero() {
            self.stalled += 1;
        }
        self.took.push(took.saturating_sub(lost));
    }

    fn worst(&self) -> Duration {
        self.took.iter().copied().max().unwrap_or_default()
    }

    fn median(&self) -> Duration {
        self.quantile(50)
    }

    /// The `percent` quantile (the lower one where it falls between two).
    fn quantile(&self, percent: usize) -> Duration {
        let mut took = self.took.clone();
        took.sort();
        took.get((took.len() * percent / 100).min(took.len().saturating_sub(1))).copied().unwrap_or_default()
    }
}

/// Watches QEMU's log for the QEMU board's "machine stalled" lines.
struct StallWatch<'a> {
    log: &'a str,
    read: u64,
}

impl<'a> StallWatch<'a> {
    fn new(log: &'a str) -> Self {
        let read = std::fs::metadata(log).map_or(0, |m| m.len());
        Self { log, read }
    }

    /// The time this PC took from the machine in the stalls the log said since the last call:
    /// each gap between two SysTicks less the 1 ms period and the firmware's critical sections
    /// ([`Stall::lost`]).
    fn since(&mut self) -> Duration {
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

/// The goal of issue #23 for an output command, write to pin: 1 ms.
const OUTPUT_LATENCY_GOAL_US: u16 = 1000;

/// `writes` DO0 writes (05), alternately on and off, each followed after 15 ms (more than the
/// 12.8 ms a refill can take) by a read of the module's own measure of that write's latency
/// (40326); the median, the 95th percentile and the worst, µs.
async fn output_latency(addr: SocketAddr, writes: u32) -> Result<(u16, u16, u16), String> {
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
async fn output_latency_check(addr: SocketAddr, model: &str, writes: u32) -> Result<(), String> {
    let (median, p95, worst) = output_latency(addr, writes).await?;
    println!(
        "qemu-{model}: DO write to the output pattern, {writes} writes: median {median} µs, 95 % {p95} µs, worst {worst} µs"
    );
    if median > OUTPUT_LATENCY_GOAL_US || p95 > OUTPUT_LATENCY_GOAL_US {
        return Err(format!("median {median} µs, 95 % {p95} µs: above {OUTPUT_LATENCY_GOAL_US} µs"));
    }
    Ok(())
}

/// A diagnostics register.
async fn diag_reg(ctx: &mut Context, d: diag::Diag) -> Result<u16, String> {
    Ok(regs(ctx, d.addr(), 1).await?[0])
}

/// The module's uptime, s (40242-40243).
async fn uptime(ctx: &mut Context) -> Result<u32, String> {
    let w = regs(ctx, diag::REG_UPTIME, 2).await?;
    Ok(u32::from(w[0]) | u32::from(w[1]) << 16)
}

/// Sets this test's password over discovery (updates are refused under the factory one); the
/// module's MAC.
async fn set_password(discovery: SocketAddr) -> Result<[u8; 6], String> {
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

/// How long the 8318 with a broken front end is watched after the revert (issue #21): three
/// trial windows, and a little more. What the watch must show is that the reverted image does
/// not run a trial of its own (the endless trial of issue #21: on trial, its self-test failing
/// as the front end does, it would restart 20 s after each start, and the bootloader would
/// start it again). Such a loop restarts once every trial window, whenever it began: its first
/// restart falls within the first window after the revert, and the uptime goes back. Three
/// windows see that restart three times over, and a loop that restarted only every second or
/// third start (a trial that passed by chance some times) at least once; longer adds nothing
/// a 20 s timer could do. The watch was 180 s before (issue #36).
const NO_RESTART_FOR: Duration = Duration::from_secs(3 * TRIAL_WINDOW_S + 2);
/// A trial window under QEMU, s: an image on trial restarts 20 s after its start when its
/// self-test has not passed (`shared::update::TRIAL`), and starts again within about 1 s
/// (docs/update.md: "reverted 21 s after its start").
const TRIAL_WINDOW_S: u64 = 21;
/// The watch polls the uptime this often.
const WATCH_POLL: Duration = Duration::from_secs(5);

/// Issue #21 (the endless trial): an 8318 whose front end fails on every channel (the board's
/// test switch, which every image started on this machine sees, as a broken AD7124-8 would)
/// takes an update (A101) that never confirms, because its self-test fails the same way. After
/// its 20 s trial the module restarts and the bootloader reverts to A100, which it started in
/// the Revert state: A100 is confirmed without a trial, so it does not restart again. Watched
/// for three trial windows ([`NO_RESTART_FOR`]: uptime never goes back, restarts counted, 0
/// wanted); then a further update is accepted (the answer to a whole session is "verified and
/// marked").
async fn broken_front_end(report: &mut Report, image: &str) {
    const REVERTED: &str = "update: an 8318 whose front end fails takes an update that never confirms; after the revert, no restart through 3 trial windows (65 s)";
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
    let qemu = match start_qemu_with(image, &ports, Some(FRONT_END_FAULT)) {
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
        // Polled every 5 s: answers all along (at most two polls missed), and the last came at
        // least the watch less two polls (55 s, over two and a half trial windows) after the
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

/// The firmware version register, once the module answers (after a restart: up to 60 s).
async fn version(addr: SocketAddr) -> Result<u16, String> {
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
async fn reverted(addr: SocketAddr, trial: u16, previous: u16) -> Result<Duration, String> {
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
async fn session(update: SocketAddr, password: &str, file: &[u8], send: usize) -> Result<Vec<u8>, String> {
    paced_session(update, password, file, send, None).await
}

/// [`session`], the firmware sent `pace.0` bytes at a time with `pace.1` between them (a slow
/// PC, so that a session lasts long enough to watch the module during it).
async fn paced_session(
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
            stream.write_all(&cnonce).await.map_err(|e| e.to_string())?;
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

/// Issue #12 through the emulated NIC: a bad signature and a truncated image are refused with
/// nothing changed; `remodaq update` takes v1 to v2 (A101), which answers after the reset; a
/// v3 (A102) that never confirms itself is reverted to v2 after its trial's reset; the
/// setting written before (DO0's pulse low width, `setting written and read back`) is intact
/// after every step.
async fn updates(report: &mut Report, image: &str, addr: SocketAddr, update: SocketAddr, discovery: SocketAddr) {
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

    // v1 -> v2 with the tool.
    let started = Instant::now();
    let tool = Command::new(std::env::var("REMODAQ").unwrap_or_else(|_| "target/debug/remodaq".into()))
        .args(["update", &addr.to_string(), &format!("{image}-v2.rdq")])
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
        "update: after v2 (counter 2), its firmware signed with counter 1 is refused (status 8), nothing changed",
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
        // v2 again: it started at least the trial's 20 s after v5 was marked (v5 ran its trial
        // and was reverted), after a software restart.
        let mut ctx = connect(addr).await?;
        let (up, cause) = (uptime(&mut ctx).await?, diag_reg(&mut ctx, diag::Diag::ResetCause).await?);
        let before_v2 = marked.elapsed().as_secs_f64() - f64::from(up);
        println!(
            "qemu-8350: v5 (link down) reverted to v2: v2 started {before_v2:.1} s after v5 was marked (versions seen {seen:04X?})"
        );
        if before_v2 < 19.0 || cause != diag::reset_cause::SOFTWARE {
            return Err(format!(
                "v2 started {before_v2:.1} s after v5 was marked, reset cause {cause}: expected after the 20 s trial, a software restart"
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
            let refused = text.contains("bootloader: the marked update is not signed with the key: not swapped");
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

/// A gap of over 5 ms between two SysTicks, as the QEMU board says it (`time.rs`): when it
/// ended, how long it was, and how much of it the firmware's critical sections held
/// (interrupts masked), µs of the guest's clock.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Stall {
    at: u64,
    gap: u64,
    masked: u64,
}

impl Stall {
    /// The time this PC took from the machine: the gap less the 1 ms SysTick period and less
    /// the firmware's critical sections. Only interrupts masked or the machine not running
    /// delay SysTick, and the board measures the first; so a stall a critical section covered
    /// excuses nothing (a critical section held 10 ms is the firmware's, however the log calls
    /// the gap it made). A PC that stopped QEMU during a critical section is counted as the
    /// firmware's too: the error is on the side of failing.
    fn lost(&self) -> u64 {
        self.gap.saturating_sub(1_000 + self.masked)
    }
}

/// The machine's stalls and the output ring's underruns (when, µs of the guest's clock) in a
/// part of QEMU's log (boards/qemu: `time.rs`, `digital.rs`). A stall line without its
/// critical sections (a board before they were measured) counts them as the whole gap: it
/// excuses nothing.
fn stalls_and_underruns(log: &str) -> (Vec<Stall>, Vec<u64>) {
    let number = |text: &str, after: &str| {
        text.split(after).nth(1).and_then(|r| r.split(' ').next()).and_then(|n| n.parse::<u64>().ok())
    };
    let (mut stalls, mut dry) = (vec![], vec![]);
    for line in log.lines() {
        if line.starts_with("qemu board: the machine stalled") {
            if let (Some(gap), Some(at)) = (number(line, "stalled "), number(line, ", at ")) {
                let masked = number(line, "; critical sections ").unwrap_or(gap);
                stalls.push(Stall { at, gap, masked });
            }
        } else if line.starts_with("qemu board: the output pattern ran dry") {
            dry.extend(number(line, ", at "));
        }
    }
    (stalls, dry)
}

/// The firmware's critical sections the QEMU board said in a part of QEMU's log: each new
/// longest of 1 ms or more (µs), and the most any stall's gap held.
fn longest_critical_section(log: &str) -> u64 {
    let number = |text: &str, after: &str| {
        text.split(after).nth(1).and_then(|r| r.split(' ').next()).and_then(|n| n.parse::<u64>().ok())
    };
    log.lines()
        .filter_map(|line| {
            if line.starts_with("qemu board: critical section ") {
                number(line, "critical section ")
            } else if line.starts_with("qemu board: the machine stalled") {
                number(line, ", the longest ")
            } else {
                None
            }
        })
        .max()
        .unwrap_or(0)
}

/// The stalls ending from 20 ms before `t` to 2 ms after (the refill that finds the ring dry
/// runs right after the stall; when the stall caught the I/O loop itself, before the SysTick
/// that says it).
fn around(stalls: &[Stall], t: u64) -> impl Iterator<Item = &Stall> {
    stalls.iter().filter(move |s| s.at + 20_000 >= t && s.at <= t + 2_000)
}

/// The time this PC took from the machine ([`Stall::lost`]) in the stalls around `t`, µs.
fn lost_around(stalls: &[Stall], t: u64) -> u64 {
    around(stalls, t).map(Stall::lost).sum()
}

/// The time the firmware's critical sections held in the stalls around `t`, µs.
fn masked_around(stalls: &[Stall], t: u64) -> u64 {
    around(stalls, t).map(|s| s.masked).sum()
}

/// Underruns the machine's stalls do not explain: less than [`EXPLAINS_US`] lost around them
/// outside critical sections, or critical sections around them as long (then the firmware
/// could have made it by itself, whatever this PC did beside).
fn unexplained_underruns(stalls: &[Stall], dry: &[u64]) -> usize {
    dry.iter().filter(|&&t| lost_around(stalls, t) < EXPLAINS_US || masked_around(stalls, t) >= EXPLAINS_US).count()
}

/// Time lost by the machine just before an underrun that explains it: half the output ring's
/// 6.4 ms slack (a firmware that kept the I/O loop waiting would have had to add the rest).
const EXPLAINS_US: u64 = 3_200;

/// The runtime every mode runs on: two worker threads.
fn runtime() -> Option<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().ok()
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    port_range(args.get(1).map_or("", String::as_str));
    if args.get(1).map(String::as_str) == Some("newcomer") {
        let (Some(image), Some(Ok(runs))) = (args.get(2), args.get(3).map(|n| n.parse::<u32>())) else {
            eprintln!("usage: qemu-e2e newcomer IMAGE RUNS");
            return ExitCode::from(2);
        };
        let Some(runtime) = runtime() else { return ExitCode::from(1) };
        let failed = (0..runs)
            .filter(|run| {
                let result = runtime.block_on(latency(image));
                if let Err(e) = &result {
                    println!("  run {}: FAILED: {e}", run + 1);
                }
                result.is_err()
            })
            .count() as u32;
        println!("newcomer: {} passed, {failed} failed", runs - failed);
        return if failed == 0 { ExitCode::SUCCESS } else { ExitCode::FAILURE };
    }
    if args.get(1).map(String::as_str) == Some("web-load") {
        // Issue #25's measure on its own, against an 8350 image under QEMU, RUNS times.
        let (Some(image), Some(Ok(runs))) = (args.get(2), args.get(3).map(|n| n.parse::<u32>())) else {
            eprintln!("usage: qemu-e2e web-load IMAGE RUNS");
            return ExitCode::from(2);
        };
        let Some(runtime) = runtime() else { return ExitCode::from(1) };
        let failed = runtime.block_on(async {
            let ports = Ports::free()?;
            let qemu = start_qemu(image, &ports)?;
            drop(wait_ready(ports.modbus()).await?);
            let web = SocketAddr::from(([127, 0, 0, 1], ports.web));
            let mut failed = 0;
            for run in 1..=runs {
                if let Err(e) = modbus_during_web_load(ports.modbus(), web, &format!("{image}.qemu.log")).await {
                    println!("  run {run}: FAILED: {e}");
                    failed += 1;
                }
            }
            drop(qemu);
            Ok::<u32, String>(failed)
        });
        return match failed {
            Ok(failed) => {
                println!("web-load: {} passed, {failed} failed", runs - failed);
                if failed == 0 {
                    ExitCode::SUCCESS
                } else {
                    ExitCode::FAILURE
                }
            }
            Err(e) => {
                eprintln!("{e}");
                ExitCode::FAILURE
            }
        };
    }
    if args.get(1).map(String::as_str) == Some("output-latency") {
        // Against a running module (the host simulator) at ADDR:PORT, or an 8350 image under QEMU.
        let (Some(target), Some(Ok(writes))) = (args.get(2), args.get(3).map(|n| n.parse::<u32>())) else {
            eprintln!("usage: qemu-e2e output-latency ADDR:PORT|IMAGE WRITES");
            return ExitCode::from(2);
        };
        let Some(runtime) = runtime() else { return ExitCode::from(1) };
        let measured = runtime.block_on(async {
            match target.parse::<SocketAddr>() {
                Ok(addr) => output_latency(addr, writes).await,
                Err(_) => {
                    let ports = Ports::free()?;
                    let qemu = start_qemu(target, &ports)?;
                    drop(wait_ready(ports.modbus()).await?);
                    let measured = output_latency(ports.modbus(), writes).await;
                    drop(qemu);
                    measured
                }
            }
        });
        return match measured {
            Ok((median, p95, worst)) => {
                println!(
                    "DO write to the output pattern, {writes} writes: median {median} µs, 95 % {p95} µs, worst {worst} µs"
                );
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("{e}");
                ExitCode::FAILURE
            }
        };
    }
    if args.get(1).map(String::as_str) == Some("latency") {
        let Some(runtime) = runtime() else { return ExitCode::from(1) };
        for image in &args[2..] {
            if let Err(e) = runtime.block_on(latency(image)) {
                println!("  {e}");
            }
        }
        return ExitCode::SUCCESS;
    }
    let (Some(model), Some(image)) = (args.get(1), args.get(2)) else {
        eprintln!("usage: qemu-e2e 8318|8350 IMAGE");
        return ExitCode::from(2);
    };
    let Some(runtime) = runtime() else { return ExitCode::from(1) };
    let mut report = runtime.block_on(run(model, image));
    report.finish(checks_of(u16::from_str_radix(model, 16).unwrap_or(0)));
    println!("qemu-{}: {} passed, {} failed", report.model, report.passed, report.failed);
    if report.failed == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lines as the QEMU board wrote them in a run on a busy PC (the critical sections added
    /// as the board says them now).
    const LOG: &str =
        "qemu board: the machine stalled 8763 us, at 13659892 us; critical sections 12 us, the longest 3 us
qemu board: the output pattern ran dry, at 13669096 us
qemu board: the machine stalled 9325 us, at 13669217 us; critical sections 25 us, the longest 4 us
bootloader: something else
qemu board: the machine stalled 2500 us, at 14496000 us; critical sections 0 us, the longest 0 us
qemu board: the machine stalled 3000 us, at 14500185 us; critical sections 0 us, the longest 0 us
qemu board: the output pattern ran dry, at 14500991 us
qemu board: the machine stalled 2100 us, at 15999000 us; critical sections 0 us, the longest 0 us
qemu board: the output pattern ran dry, at 16000000 us
";

    #[test]
    fn underruns_after_the_machine_lost_time_are_the_pcs() {
        let (stalls, dry) = stalls_and_underruns(LOG);
        assert_eq!(stalls[0], Stall { at: 13_659_892, gap: 8_763, masked: 12 });
        assert_eq!(stalls.len(), 5);
        assert_eq!(dry, [13_669_096, 14_500_991, 16_000_000]);
        // The first follows (or, caught in the I/O loop, precedes by 121 µs) long stalls; the
        // second two short ones that lost 1.5 + 2 ms; the third only 1.1 ms lost.
        assert_eq!(lost_around(&stalls, 14_500_991), 3_500);
        assert_eq!(unexplained_underruns(&stalls, &dry), 1);
        assert_eq!(unexplained_underruns(&[], &dry), 3);
    }

    /// A critical section of the firmware that held SysTick off makes the same gap as a stall of
    /// the PC, and the same underrun; it explains nothing.
    #[test]
    fn a_critical_section_is_the_firmwares() {
        let log = "qemu board: critical section 10012 us, the longest yet, at 13659892 us
qemu board: the machine stalled 10230 us, at 13659892 us; critical sections 10040 us, the longest 10012 us
qemu board: the output pattern ran dry, at 13659990 us
qemu board: the machine stalled 12000 us, at 20000000 us; critical sections 4000 us, the longest 4000 us
";
        let (stalls, dry) = stalls_and_underruns(log);
        assert_eq!(stalls[0].lost(), 0);
        assert_eq!(unexplained_underruns(&stalls, &dry), 1);
        // A stall of this PC just before does not explain an underrun a critical section of the
        // firmware could have made by itself.
        let both = format!(
            "qemu board: the machine stalled 8000 us, at 13650000 us; critical sections 3 us, the longest 2 us\n{log}"
        );
        let (stalls, dry) = stalls_and_underruns(&both);
        assert_eq!(lost_around(&stalls, dry[0]), 6_997);
        assert_eq!(unexplained_underruns(&stalls, &dry), 1);
        // Partly covered: only the part no critical section held is the PC's.
        let (stalls, _) = stalls_and_underruns(log);
        assert_eq!(stalls[1].lost(), 7_000);
        assert_eq!(longest_critical_section(log), 10_012);
        // A line of a board that did not measure them excuses nothing.
        let (old, _) = stalls_and_underruns("qemu board: the machine stalled 8763 us, at 13659892 us\n");
        assert_eq!(old, [Stall { at: 13_659_892, gap: 8_763, masked: 8_763 }]);
        assert_eq!(old[0].lost(), 0);
    }
}
