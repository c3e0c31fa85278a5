//! The Modbus checks: live values, a setting written and read back, 8 clients at once,
//! pipelining, a newcomer during a 64-connection flood, and the `latency` mode's figures.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use remodaq_protocol::identity::REG_NAME;
use remodaq_protocol::m8318::{REG_CJC, REG_INPUT_TYPE, REG_VALUE};
use remodaq_protocol::m8350::{Point, PulseField, Word, REG_ALL_DI, REG_DI_MODE};
use tokio::time::{sleep, timeout};
use tokio_modbus::client::Context;

use crate::client::{connect, regs, regs_until, wait_ready, write, STEP};
use crate::qemu::{start_qemu, Ports, FLOOD};

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

pub(crate) async fn live_values(model: u16, ctx: &mut Context) -> Result<(), String> {
    if model == 0x8318 {
        live_values_8318(ctx).await
    } else {
        live_values_8350(ctx).await
    }
}

pub(crate) async fn setting_round_trip(model: u16, ctx: &mut Context) -> Result<(), String> {
    let pulse_low = Point::Pulse(PulseField::Low, 0, Word::Low).addr().1;
    let (addr, values): (u16, &[u16]) = if model == 0x8318 { (REG_INPUT_TYPE, &[0x0E]) } else { (pulse_low, &[25, 0]) };
    write(ctx, addr, values).await?;
    let back = regs(ctx, addr, values.len() as u16).await?;
    if back != values {
        return Err(format!("wrote {values:x?} to {addr:#x}, read {back:x?}"));
    }
    Ok(())
}

/// A read of 40211 as raw bytes (transaction id `id`).
fn request(id: u16) -> [u8; 12] {
    let [t0, t1] = id.to_be_bytes();
    let [r0, r1] = REG_NAME.to_be_bytes();
    [t0, t1, 0, 0, 0, 6, 1, 3, r0, r1, 0, 1]
}

/// Sends `count` requests in one write and waits for all the answers (11 bytes each).
pub(crate) async fn burst(stream: &mut tokio::net::TcpStream, count: u16) -> Result<Duration, String> {
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

pub(crate) fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

/// One request at a time (median of 20), then 10 pipelined in one segment (median of 5):
/// the module answers every buffered request and flushes once, so the burst costs little
/// more than one request. Returns (single, burst).
pub(crate) async fn pipelining(addr: SocketAddr, limit: f64) -> Result<(Duration, Duration), String> {
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
pub(crate) fn newcomer_limit(single: Duration) -> Duration {
    (single * (FLOOD as u32 + 1) * 10).clamp(Duration::from_millis(300), Duration::from_millis(900))
}

/// 64 clients connect at once, each through its own forwarded port, and each sends a request
/// (not waiting for its answer); right behind them a newcomer reads 40211. Spec: the newcomer
/// is answered, not reset (docs/modbus.md), and it does not wait beyond `limit`. A newcomer
/// the guest refused (QEMU then closes the connection) fails as "reset"; one answered late
/// fails as "waited".
pub(crate) async fn newcomer(ports: &Ports, model: u16, limit: Duration) -> Result<Duration, String> {
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
pub(crate) async fn latency(image: &str) -> Result<(), String> {
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

pub(crate) async fn eight_clients(addr: SocketAddr, model: u16) -> Result<(), String> {
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
