//! End to end: the host build of the 8350 on a loopback port, a 1 kHz square wave on DI0 from
//! the scenario file, DI1 wired to DO0 (`from_do`), driven by tokio-modbus.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use remodaq_board_host::testing::SimModule;
use tokio::time::{sleep, timeout};
use tokio_modbus::client::{tcp, Context, Reader, Writer};
use tokio_modbus::ExceptionCode;

const BIN: &str = env!("CARGO_BIN_EXE_firmware-8350");
const LIMIT: Duration = Duration::from_secs(10);

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("remodaq-e2e-8350-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

async fn connect(module: &SimModule) -> Context {
    timeout(LIMIT, tcp::connect(module.addr)).await.expect("connect in time").expect("connect")
}

async fn regs(ctx: &mut Context, addr: u16, n: u16) -> Vec<u16> {
    timeout(LIMIT, ctx.read_holding_registers(addr, n)).await.unwrap().unwrap().expect("no exception")
}

async fn bits(ctx: &mut Context, addr: u16, n: u16) -> Vec<bool> {
    timeout(LIMIT, ctx.read_coils(addr, n)).await.unwrap().unwrap().expect("no exception")
}

async fn write_reg(ctx: &mut Context, addr: u16, value: u16) {
    let r = timeout(LIMIT, ctx.write_single_register(addr, value)).await.unwrap().unwrap();
    assert_eq!(r, Ok(()), "write {value:#x} to {addr:#x}");
}

async fn write_regs(ctx: &mut Context, addr: u16, values: &[u16]) {
    let r = timeout(LIMIT, ctx.write_multiple_registers(addr, values)).await.unwrap().unwrap();
    assert_eq!(r, Ok(()), "write {values:x?} to {addr:#x}");
}

async fn write_bit(ctx: &mut Context, addr: u16, on: bool) {
    let r = timeout(LIMIT, ctx.write_single_coil(addr, on)).await.unwrap().unwrap();
    assert_eq!(r, Ok(()), "write {on} to bit {addr:#x}");
}

async fn counter(ctx: &mut Context, n: u16) -> u32 {
    let v = regs(ctx, 2 * n, 2).await;
    u32::from(v[0]) | u32::from(v[1]) << 16
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn square_wave_counter_frequency_latch_pulses_and_restart() {
    let scenario = temp("scenario.toml");
    std::fs::write(&scenario, "[di0]\nsquare_hz = 1000.0\n[di1]\nfrom_do = 0\n[di2]\nlevel = false\n").unwrap();
    let flash = temp("module.flash");
    let _ = std::fs::remove_file(&flash);
    let args = ["--listen", "127.0.0.1:0", "--scenario", scenario.to_str().unwrap()];
    let module = SimModule::start_with(BIN, &flash, &args);
    let mut ctx = connect(&module).await;

    // Counter mode on DI0: 1000 edges per second of the module's clock. Each read's count is
    // that of a moment between sending the request and receiving the answer, less the
    // module's lag: samples are handed to the engine every 2 ms, and we allow 50 ms more for a
    // loaded machine scheduling the module late. So over a window of 1.5 s the count is known
    // to within about 3.5 %, not a rate guessed at.
    const LAG: f64 = 0.002 + 0.050;
    write_reg(&mut ctx, 0x100, 1).await;
    let t1_sent = Instant::now();
    let c1 = counter(&mut ctx, 0).await;
    let t1_back = Instant::now();
    sleep(Duration::from_millis(1500)).await;
    let t2_sent = Instant::now();
    let c2 = counter(&mut ctx, 0).await;
    let t2_back = Instant::now();
    let shortest = (t2_sent - t1_back).as_secs_f64() - LAG;
    let longest = (t2_back - t1_sent).as_secs_f64() + LAG;
    let counted = f64::from(c2 - c1);
    assert!(
        (1000.0 * shortest - 1.0..=1000.0 * longest + 1.0).contains(&counted),
        "counted {counted} in a window of {shortest:.3} to {longest:.3} s at 1000 Hz"
    );
    // Stopped: the count stays.
    write_bit(&mut ctx, 0x20, false).await;
    let stopped = counter(&mut ctx, 0).await;
    sleep(Duration::from_millis(300)).await;
    assert_eq!(counter(&mut ctx, 0).await, stopped, "a stopped counter does not count");
    write_bit(&mut ctx, 0x20, true).await;
    sleep(Duration::from_millis(200)).await;
    assert!(counter(&mut ctx, 0).await > stopped, "restarted");

    // Frequency mode: 1000 Hz after the first full gate.
    write_reg(&mut ctx, 0x100, 4).await;
    let deadline = Instant::now() + Duration::from_secs(5);
    let hz = loop {
        let hz = counter(&mut ctx, 0).await;
        if hz != 0 || Instant::now() > deadline {
            break hz;
        }
        sleep(Duration::from_millis(100)).await;
    };
    // Exact: the square wave has 50 samples a period at 50 kHz, and the gate is 50 000 samples.
    assert_eq!(hz, 1000, "frequency");

    // Low-to-high latch on DI2: set by an edge (the scenario changes), cleared by the read.
    write_reg(&mut ctx, 0x102, 2).await;
    assert_eq!(bits(&mut ctx, 0x2B, 1).await, vec![false]);
    std::fs::write(&scenario, "[di0]\nsquare_hz = 1000.0\n[di1]\nfrom_do = 0\n[di2]\nlevel = true\n").unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    while !bits(&mut ctx, 0x02, 1).await[0] {
        assert!(Instant::now() < deadline, "DI2 never went high");
        sleep(Duration::from_millis(50)).await;
    }
    assert_eq!(bits(&mut ctx, 0x2B, 1).await, vec![true], "latched");
    assert_eq!(bits(&mut ctx, 0x2B, 1).await, vec![false], "cleared by the read");
    assert_eq!(regs(&mut ctx, 0x12C, 1).await[0] & 0b100, 0b100, "all-DI register");

    // A pulse train on DO0: 1 ms high, 1 ms low, 250 pulses = 0.5 s, then off. DI1, wired to
    // DO0, counts its pulses.
    write_reg(&mut ctx, 0x101, 1).await;
    write_bit(&mut ctx, 0x25, true).await; // clear DI1's counter
    assert_eq!(counter(&mut ctx, 1).await, 0, "DO0 is off: DI1 counted nothing");
    write_reg(&mut ctx, 0x110, 1).await;
    write_regs(&mut ctx, 0x18, &[10, 0]).await; // low width
    write_regs(&mut ctx, 0x24, &[10, 0]).await; // high width
    write_regs(&mut ctx, 0x30, &[250, 0]).await; // count
    write_bit(&mut ctx, 0x10, true).await;
    let started = Instant::now();
    assert_eq!(bits(&mut ctx, 0x10, 1).await, vec![true], "running");
    while bits(&mut ctx, 0x10, 1).await[0] {
        assert!(started.elapsed() < Duration::from_secs(5), "the train never ended");
        sleep(Duration::from_millis(20)).await;
    }
    // The train is 5000 ticks (500 ms) of the module's clock. The engine computes the output
    // 64 to 128 ticks ahead of what is played (the output ring), so its DO bit drops 487.2 to
    // 500 ms after the start; we poll every 20 ms and allow 100 ms for a loaded machine.
    let took = started.elapsed();
    assert!(
        took >= Duration::from_micros(487_200) && took <= Duration::from_millis(500 + 20 + 100),
        "train took {took:?}"
    );
    assert_eq!(regs(&mut ctx, 0x12E, 1).await, vec![0], "output off after the last pulse");
    // The DO bit drops when the engine has computed the last pulse, up to 12.8 ms before it is
    // played: wait for the count to arrive, then give extra pulses, were there any, time to
    // show.
    let deadline = Instant::now() + Duration::from_secs(5);
    while counter(&mut ctx, 1).await < 250 && Instant::now() < deadline {
        sleep(Duration::from_millis(10)).await;
    }
    sleep(Duration::from_millis(100)).await;
    assert_eq!(counter(&mut ctx, 1).await, 250, "DI1 counted the pulses of DO0's train (spec §3.4: 250)");

    // Modes and pulse settings survive a restart; counters and outputs do not persist.
    module.kill();
    let module = SimModule::start_with(BIN, &flash, &args);
    let mut ctx = connect(&module).await;
    assert_eq!(regs(&mut ctx, 0x100, 3).await, vec![4, 1, 2]);
    assert_eq!(regs(&mut ctx, 0x110, 1).await, vec![1]);
    assert_eq!(regs(&mut ctx, 0x18, 2).await, vec![10, 0]);
    assert_eq!(regs(&mut ctx, 0x24, 2).await, vec![10, 0]);
    assert_eq!(regs(&mut ctx, 0x30, 2).await, vec![250, 0]);
    assert_eq!(bits(&mut ctx, 0x10, 1).await, vec![false]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn identity_and_exceptions() {
    let flash = temp("identity.flash");
    let _ = std::fs::remove_file(&flash);
    let module = SimModule::start(BIN, &flash);
    let mut ctx = connect(&module).await;
    assert_eq!(regs(&mut ctx, 0xD2, 1).await, vec![0x8350]);
    let version = timeout(LIMIT, ctx.read_input_registers(0xD4, 1)).await.unwrap().unwrap();
    assert_eq!(version, Ok(vec![0xA100]));
    let w = timeout(LIMIT, ctx.write_single_register(0xD4, 0xA200)).await.unwrap().unwrap();
    assert_eq!(w, Err(ExceptionCode::IllegalDataAddress), "version is read only (decision)");
    let w = timeout(LIMIT, ctx.write_single_register(0x100, 9)).await.unwrap().unwrap();
    assert_eq!(w, Err(ExceptionCode::IllegalDataValue));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn diagnostics_samples_lost_injected_and_cleared() {
    // Extensions §1, 8350: module status bit 0 = input samples lost since the last read of
    // the module status register.
    let scenario = temp("diag-scenario.toml");
    std::fs::write(&scenario, "[di0]\nlevel = true\n").unwrap();
    let flash = temp("diag.flash");
    let _ = std::fs::remove_file(&flash);
    let module =
        SimModule::start_with(BIN, &flash, &["--listen", "127.0.0.1:0", "--scenario", scenario.to_str().unwrap()]);
    let mut ctx = connect(&module).await;
    let status = async |ctx: &mut Context| regs(ctx, 0xF0, 1).await[0];
    let deadline = Instant::now() + Duration::from_secs(5);
    while status(&mut ctx).await != 0 {
        assert!(Instant::now() < deadline, "inputs never became valid");
        sleep(Duration::from_millis(50)).await;
    }
    assert_eq!(regs(&mut ctx, 0xF3, 1).await, vec![0], "reset cause power-on");
    // The capture loses samples: bit 0, and it stays set while they are lost.
    std::fs::write(&scenario, "[di0]\nlevel = true\n[capture]\nlose_samples = true\n").unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    while status(&mut ctx).await & 1 == 0 {
        assert!(Instant::now() < deadline, "lost samples never reported");
        sleep(Duration::from_millis(50)).await;
    }
    sleep(Duration::from_millis(100)).await;
    assert_eq!(status(&mut ctx).await & 1, 1, "set again by the next loss");
    // The capture recovers (the scenario is re-read within 10 ms of samples): the bit is
    // cleared by the first read after the last loss, and stays clear.
    std::fs::write(&scenario, "[di0]\nlevel = true\n").unwrap();
    sleep(Duration::from_millis(300)).await;
    let _ = status(&mut ctx).await;
    for _ in 0..5 {
        sleep(Duration::from_millis(50)).await;
        assert_eq!(status(&mut ctx).await, 0, "no loss after the capture recovered");
    }
    assert_eq!(regs(&mut ctx, 0x12C, 1).await[0] & 1, 1, "DI0 still seen");
}

/// Spec §3.3: counters count every edge of a square wave up to 3 kHz on all 12 channels at
/// once, through the module's capture path (the host board samples the scenario at 50 kHz and
/// hands the samples to the engine as the STM32's capture ring does). All 12 counters are read
/// in one request, so they come from one moment: they must agree to the edge, and the count over
/// a window bracketed by the requests must be 3000 per second of it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_khz_on_all_twelve_channels() {
    let scenario = temp("3khz.toml");
    let text: String = (0..12).map(|n| format!("[di{n}]\nsquare_hz = 3000.0\n")).collect();
    std::fs::write(&scenario, text).unwrap();
    let flash = temp("3khz.flash");
    let _ = std::fs::remove_file(&flash);
    let module =
        SimModule::start_with(BIN, &flash, &["--listen", "127.0.0.1:0", "--scenario", scenario.to_str().unwrap()]);
    let mut ctx = connect(&module).await;
    write_regs(&mut ctx, 0x100, &[1; 12]).await;
    let all = async |ctx: &mut Context| -> Vec<u32> {
        regs(ctx, 0, 24).await.chunks(2).map(|w| u32::from(w[0]) | u32::from(w[1]) << 16).collect()
    };
    const LAG: f64 = 0.002 + 0.050;
    let t1_sent = Instant::now();
    let c1 = all(&mut ctx).await;
    let t1_back = Instant::now();
    sleep(Duration::from_millis(1000)).await;
    let t2_sent = Instant::now();
    let c2 = all(&mut ctx).await;
    let t2_back = Instant::now();
    let counted: Vec<u32> = c2.iter().zip(&c1).map(|(b, a)| b - a).collect();
    assert!(counted.iter().all(|c| c.abs_diff(counted[0]) <= 1), "every channel counts the same edges: {counted:?}");
    let (shortest, longest) = ((t2_sent - t1_back).as_secs_f64() - LAG, (t2_back - t1_sent).as_secs_f64() + LAG);
    for c in &counted {
        assert!(
            (3000.0 * shortest - 1.0..=3000.0 * longest + 1.0).contains(&f64::from(*c)),
            "counted {c} in {shortest:.3} to {longest:.3} s at 3000 Hz"
        );
    }
}
