//! End to end: the host build of the 8318 on a loopback port, driven by tokio-modbus.

use std::net::SocketAddr;
use std::time::Duration;

use remodaq_board_host::testing::SimModule;
use tokio::time::timeout;
use tokio_modbus::client::{tcp, Context, Reader, Writer};
use tokio_modbus::ExceptionCode;

const BIN: &str = env!("CARGO_BIN_EXE_firmware-8318");
const LIMIT: Duration = Duration::from_secs(10);

async fn connect(addr: SocketAddr) -> Context {
    timeout(LIMIT, tcp::connect(addr)).await.expect("connect in time").expect("connect")
}

/// A connection from the loopback address `from` (a module takes at most 4 connections from one
/// address: docs/modbus.md, so tests of many clients give each its own).
async fn connect_from(from: [u8; 4], addr: SocketAddr) -> Context {
    tcp::attach(stream_from(from, addr).await)
}

async fn stream_from(from: [u8; 4], addr: SocketAddr) -> tokio::net::TcpStream {
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.bind(SocketAddr::from((from, 0))).expect("bind a loopback source");
    timeout(LIMIT, socket.connect(addr)).await.expect("connect in time").expect("connect")
}

async fn read(ctx: &mut Context, addr: u16, n: u16) -> Result<Vec<u16>, ExceptionCode> {
    timeout(LIMIT, ctx.read_holding_registers(addr, n)).await.expect("answer in time").expect("transport")
}

/// A fresh (removed) file in this test run's temp dir.
fn flash_file(name: &str) -> std::path::PathBuf {
    let path = flash_file_keep(name);
    let _ = std::fs::remove_file(&path);
    path
}

/// The same path as [`flash_file`], content kept (for a restart).
fn flash_file_keep(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("remodaq-e2e-8318-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn identity_registers_and_exceptions() {
    let module = SimModule::start(BIN, &flash_file("identity.flash"));
    let mut ctx = connect(module.addr).await;
    assert_eq!(read(&mut ctx, 0xD2, 1).await, Ok(vec![0x8318]));
    assert_eq!(read(&mut ctx, 0xD4, 1).await, Ok(vec![0xA100]));
    let input = timeout(LIMIT, ctx.read_input_registers(0xD2, 1)).await.unwrap().unwrap();
    assert_eq!(input, Ok(vec![0x8318]));
    assert_eq!(read(&mut ctx, 0xD3, 1).await, Err(ExceptionCode::IllegalDataAddress));
    // The 8318 has no bits.
    let coils = timeout(LIMIT, ctx.read_coils(0, 1)).await.unwrap().unwrap();
    assert_eq!(coils, Err(ExceptionCode::IllegalDataAddress));
    let w = timeout(LIMIT, ctx.write_single_register(0xD4, 1)).await.unwrap().unwrap();
    assert_eq!(w, Err(ExceptionCode::IllegalDataAddress));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn settings_survive_a_restart() {
    let flash = flash_file("restart.flash");
    let module = SimModule::start(BIN, &flash);
    let mut ctx = connect(module.addr).await;
    assert_eq!(read(&mut ctx, 0xC8, 1).await, Ok(vec![0x0F]), "factory type K");
    let w = timeout(LIMIT, ctx.write_single_register(0xC8, 0x12)).await.unwrap().unwrap();
    assert_eq!(w, Ok(()));
    let w = timeout(LIMIT, ctx.write_single_register(0xC8, 0x07)).await.unwrap().unwrap();
    assert_eq!(w, Err(ExceptionCode::IllegalDataValue), "07 is not a type code");
    let w = timeout(LIMIT, ctx.write_single_register(0xDC, 0x00A5)).await.unwrap().unwrap();
    assert_eq!(w, Ok(()));
    let w = timeout(LIMIT, ctx.write_single_register(0xD7, 0xFF38)).await.unwrap().unwrap(); // -2.00 °C
    assert_eq!(w, Ok(()));
    // Killed right after the acknowledgements: the settings must be in the image already.
    module.kill();
    let module = SimModule::start(BIN, &flash);
    let mut ctx = connect(module.addr).await;
    assert_eq!(read(&mut ctx, 0xC8, 1).await, Ok(vec![0x12]));
    assert_eq!(read(&mut ctx, 0xD7, 1).await, Ok(vec![0xFF38]));
    assert_eq!(read(&mut ctx, 0xDC, 1).await, Ok(vec![0x00A5]));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ninth_client_is_served_and_the_longest_idle_is_closed() {
    let module = SimModule::start(BIN, &flash_file("nine.flash"));
    let mut clients = Vec::new();
    for client in 0..8 {
        let mut ctx = connect_from([127, 0, 1, client], module.addr).await;
        assert_eq!(read(&mut ctx, 0xD2, 1).await, Ok(vec![0x8318]));
        clients.push(ctx);
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // Client 0 is now the longest idle; the 9th client must still get answers.
    let mut ninth = connect(module.addr).await;
    assert_eq!(read(&mut ninth, 0xD4, 1).await, Ok(vec![0xA100]));
    // Clients 1..8 are still served.
    for ctx in clients.iter_mut().skip(1) {
        assert_eq!(read(ctx, 0xD2, 1).await, Ok(vec![0x8318]));
    }
    // Client 0 was closed to make room.
    let evicted = timeout(LIMIT, clients[0].read_holding_registers(0xD2, 1)).await.expect("no hang");
    assert!(evicted.is_err(), "longest-idle connection should have been closed: {evicted:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nine_simultaneous_clients_all_get_answers() {
    let module = SimModule::start(BIN, &flash_file("busy.flash"));
    let addr = module.addr;
    let mut tasks = Vec::new();
    for client in 0..9u16 {
        tasks.push(tokio::spawn(async move {
            // Each client asks 30 times; a connection closed to make room is reopened.
            let mut answers = 0;
            let mut reconnects = 0;
            let from = [127, 0, 1, client as u8];
            let mut ctx = connect_from(from, addr).await;
            while answers < 30 {
                match timeout(LIMIT, ctx.read_holding_registers(0xD2, 1)).await.expect("answer in time") {
                    Ok(Ok(v)) => {
                        assert_eq!(v, vec![0x8318], "client {client}");
                        answers += 1;
                    }
                    Ok(Err(e)) => panic!("client {client}: exception {e:?}"),
                    Err(_) => {
                        reconnects += 1;
                        assert!(reconnects < 100, "client {client} kept losing its connection");
                        ctx = connect_from(from, addr).await;
                    }
                }
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
            reconnects
        }));
    }
    let mut total_reconnects = 0;
    for task in tasks {
        total_reconnects += timeout(Duration::from_secs(60), task).await.expect("clients finish").expect("client ok");
    }
    eprintln!("9 clients x 30 answers; connections closed to make room: {total_reconnects}");
}

/// Reads `n` registers until `check` accepts them (values change at the next 100 ms cycle).
async fn read_until(ctx: &mut Context, addr: u16, n: u16, check: impl Fn(&[u16]) -> bool) -> Vec<u16> {
    let mut last = Vec::new();
    for _ in 0..100 {
        last = read(ctx, addr, n).await.expect("no exception");
        if check(&last) {
            return last;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!("registers {addr:#06x}+{n} stayed at {last:04x?}");
}

async fn write(ctx: &mut Context, addr: u16, value: u16) {
    let w = timeout(LIMIT, ctx.write_single_register(addr, value)).await.unwrap().unwrap();
    assert_eq!(w, Ok(()), "write {value:#06x} to {addr:#06x}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scenario_values_over_modbus() {
    let dir = flash_file("scenario").with_extension("d");
    std::fs::create_dir_all(&dir).unwrap();
    let scenario = dir.join("scenario.toml");
    std::fs::write(
        &scenario,
        "cjc_celsius = 25.0\n[ch0]\nmillivolts = 41.276\n[ch1]\nvolts = 1.2\n[ch2]\nmilliamps = 12.0\n[ch3]\nopen = true\n",
    )
    .unwrap();
    let module = SimModule::start_with(
        BIN,
        &flash_file("scenario.flash"),
        &["--listen", "127.0.0.1:0", "--scenario", scenario.to_str().unwrap()],
    );
    let mut ctx = connect(module.addr).await;

    // Type K (factory, spec range -250 .. 1400 °C): 41.276 mV at the terminals, cold junction
    // at 25 °C. By the NIST ITS-90 type K table, E(25 °C) = 1.000 mV, so the hot junction sees
    // 42.276 mV, between E(1025 °C) = 42.247 and E(1026 °C) = 42.286 mV: 1025.74 °C. The
    // table's 0.0005 mV rounding is 0.013 °C per value at 39 µV/°C: allow 2 counts (0.05 °C).
    let t = 1025.0 + (42.276 - 42.247) / (42.286 - 42.247);
    let expected = (t + 250.0) / 1650.0 * 65535.0;
    let v = read_until(&mut ctx, 0, 9, |v| v[8] == 2500).await;
    assert!((f64::from(v[0]) - expected).abs() <= 2.0, "thermocouple channel {:04X}, want {expected:.1}", v[0]);
    assert_eq!(v[3], 0xFFFF, "open thermocouple");
    // 0 mV reads the cold junction itself: (25 + 250) / 1650 * 65535 = 10922.5.
    assert!((f64::from(v[4]) - 10922.5).abs() <= 1.0, "0 mV reads the cold junction temperature: {}", v[4]);

    // ±2.5 V: channel 1 at 1.2 V.
    write(&mut ctx, 0xC8, 0x05).await;
    let v = read_until(&mut ctx, 0, 9, |v| v[4] == 0x8000).await;
    // (1200 + 2500) / 5000 * 65535 = 48495.9.
    assert_eq!(v[1], 48496, "voltage channel");

    // ±20 mA: channel 2 at 12 mA.
    write(&mut ctx, 0xC8, 0x06).await;
    let v = read_until(&mut ctx, 0, 9, |v| v[2] == 52428).await;
    // (12 + 20) / 40 * 65535 = 52428.0; 1.2 V on the 100 ohm shunt is 12 mA too.
    assert_eq!(v[2], 52428, "current channel");
    assert_eq!(v[1], 52428, "1.2 V on the 100 ohm shunt reads 12 mA");

    // Disabling channels reads 0000h; a CJC offset of -2.00 °C shows in 40009.
    write(&mut ctx, 0xDC, 0x00F0).await;
    write(&mut ctx, 0xD7, 0xFF38).await;
    let v = read_until(&mut ctx, 0, 9, |v| v[8] == 2300).await;
    assert_eq!(v[..4], [0, 0, 0, 0]);

    // The scenario file is re-read when it changes.
    std::fs::write(&scenario, "cjc_celsius = 30.0\n[ch4]\nmilliamps = -20.0\n").unwrap();
    let v = read_until(&mut ctx, 0, 9, |v| v[8] == 2800).await;
    assert_eq!(v[4], 0);

    // Type code, enable mask and CJC offset survive a restart.
    module.kill();
    let module = SimModule::start_with(
        BIN,
        &flash_file_keep("scenario.flash"),
        &["--listen", "127.0.0.1:0", "--scenario", scenario.to_str().unwrap()],
    );
    let mut ctx = connect(module.addr).await;
    assert_eq!(read(&mut ctx, 0xC8, 1).await, Ok(vec![0x06]));
    assert_eq!(read(&mut ctx, 0xD7, 1).await, Ok(vec![0xFF38]));
    assert_eq!(read(&mut ctx, 0xDC, 1).await, Ok(vec![0x00F0]));
    read_until(&mut ctx, 0, 9, |v| v[8] == 2800 && v[..4] == [0; 4]).await;
}

#[test]
fn bad_scenario_is_a_clear_error() {
    let dir = flash_file("bad").with_extension("d");
    std::fs::create_dir_all(&dir).unwrap();
    let scenario = dir.join("bad.toml");
    std::fs::write(&scenario, "[ch0]\nmillivolts = 1.0\nvolts = 2.0\n").unwrap();
    let out = std::process::Command::new(BIN)
        .args(["--listen", "127.0.0.1:0", "--discovery", "127.0.0.1:0", "--flash"])
        .arg(flash_file("bad.flash"))
        .arg("--scenario")
        .arg(&scenario)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("line 1") && stderr.contains("exactly one"), "{stderr}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn diagnostics_registers_with_faults_injected_and_cleared() {
    // Extensions §1: 40241 module status, 40242-3 uptime, 40244 reset cause, 40245
    // connections, 40246-7 requests, 40248 exceptions.
    let dir = flash_file("diag").with_extension("d");
    std::fs::create_dir_all(&dir).unwrap();
    let scenario = dir.join("scenario.toml");
    std::fs::write(&scenario, "[ch0]\nmillivolts = 1.0\n").unwrap();
    let module = SimModule::start_with(
        BIN,
        &flash_file("diag.flash"),
        &["--listen", "127.0.0.1:0", "--scenario", scenario.to_str().unwrap()],
    );
    let mut ctx = connect(module.addr).await;
    // After the first cycle: no fault; started by power-on; this client connected.
    let d = read_until(&mut ctx, 0xF0, 8, |d| d[0] == 0).await;
    assert_eq!((d[3], d[4]), (0, 1), "reset cause power-on, one client");
    let requests = u32::from(d[5]) | u32::from(d[6]) << 16;
    assert!(requests >= 1, "{d:?}");
    // An exception counts.
    assert_eq!(read(&mut ctx, 0x1000, 1).await, Err(ExceptionCode::IllegalDataAddress));
    let d = read(&mut ctx, 0xF0, 8).await.unwrap();
    assert_eq!(d[7], 1, "one exception so far");
    assert!(u32::from(d[5]) | u32::from(d[6]) << 16 >= requests + 2);
    // Writes to a diagnostics register: exception 02 (read only).
    assert_eq!(
        timeout(Duration::from_secs(5), ctx.write_single_register(0xF0, 0)).await.unwrap().unwrap(),
        Err(ExceptionCode::IllegalDataAddress)
    );
    // The front end and the cold-junction sensor fail: bits 0 and 1; thermocouples FFFFh.
    std::fs::write(&scenario, "[frontend]\nfault = true\n[cjc]\nfault = true\n").unwrap();
    let d = read_until(&mut ctx, 0xF0, 1, |d| d[0] == 0b11).await;
    assert_eq!(d, vec![0b11]);
    assert_eq!(read(&mut ctx, 0, 9).await.unwrap()[8], 0x7FFF, "40009 without a cold junction");
    // Cleared: the next good cycle clears both.
    std::fs::write(&scenario, "[ch0]\nmillivolts = 1.0\n").unwrap();
    read_until(&mut ctx, 0xF0, 1, |d| d[0] == 0).await;
    // Only the cold junction: bit 1 alone.
    std::fs::write(&scenario, "[cjc]\nfault = true\n").unwrap();
    read_until(&mut ctx, 0xF0, 1, |d| d[0] == 0b10).await;
    // Uptime counts seconds.
    let up = |d: &[u16]| u32::from(d[1]) | u32::from(d[2]) << 16;
    let before = up(&read(&mut ctx, 0xF0, 3).await.unwrap());
    tokio::time::sleep(Duration::from_millis(2100)).await;
    let after = up(&read(&mut ctx, 0xF0, 3).await.unwrap());
    assert!((2..=3).contains(&(after - before)), "{before} -> {after}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_newcomer_is_answered_during_a_flood_of_64_connections() {
    // 64 connections open at once and stay silent; then a newcomer asks for 40211. The eviction
    // rule makes room (the longest idle goes) and the newcomer is answered, not reset. A
    // connection not heard from is kept for its first GRACE_MS (its request may be on the
    // way), so the 64 silent ones ahead of the newcomer make room about 8 at a time, one round
    // each GRACE_MS: about 8 rounds (0.3 s seen); the bound allows 8 + 4.
    let module = SimModule::start(BIN, &flash_file("flood.flash"));
    let addr = module.addr;
    let flood: Vec<_> = (0..64).map(|i| tokio::spawn(stream_from([127, 0, 3, i], addr))).collect();
    let mut open = Vec::new();
    for c in flood {
        if let Ok(stream) = c.await {
            open.push(stream);
        }
    }
    let started = std::time::Instant::now();
    let mut ctx = connect(addr).await;
    assert_eq!(read(&mut ctx, 0xD2, 1).await, Ok(vec![0x8318]), "the newcomer is answered, not reset");
    let took = started.elapsed();
    eprintln!("newcomer answered {took:?} after {} flood connections were opened", open.len());
    let rounds = 64 / 8 + 4;
    let limit = Duration::from_millis(rounds * remodaq_modbus::server::GRACE_MS);
    assert!(took < limit, "the newcomer waited {took:?}, limit {limit:?}");
}

/// docs/modbus.md: one address holds at most 4 connections; its fifth closes its own idlest,
/// never another client's.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_address_cannot_push_other_clients_out() {
    let module = SimModule::start(BIN, &flash_file("per-source.flash"));
    let mut master = connect_from([127, 0, 0, 1], module.addr).await;
    assert_eq!(read(&mut master, 0xD2, 1).await, Ok(vec![0x8318]));
    let mut hog = Vec::new();
    for _ in 0..12 {
        let mut ctx = connect_from([127, 0, 0, 66], module.addr).await;
        assert_eq!(read(&mut ctx, 0xD2, 1).await, Ok(vec![0x8318]), "each new one is served");
        hog.push(ctx);
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // 12 connections from one address, the master idle the longest: the master still answers,
    // and only the hog's 4 newest are open.
    assert_eq!(read(&mut master, 0xD4, 1).await, Ok(vec![0xA100]), "the master is never closed for them");
    let mut open = 0;
    for ctx in &mut hog {
        if matches!(timeout(LIMIT, ctx.read_holding_registers(0xD2, 1)).await.expect("no hang"), Ok(Ok(_))) {
            open += 1;
        }
    }
    assert_eq!(open, 4, "one address holds at most 4");
}

/// Extensions §2: every channel status produced from a scenario and read over Modbus, in the
/// same cycle as its value; the open-input value both ways, persisted across a restart.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn channel_status_and_open_input_value() {
    let dir = flash_file("status").with_extension("d");
    std::fs::create_dir_all(&dir).unwrap();
    let scenario = dir.join("scenario.toml");
    // Type K (factory), cold junction 25 °C, E(25 °C) = 1.000 mV (NIST). ch1: 60 + 1 mV is
    // above E(1372 °C) = 54.886 mV, the top of the NIST function: over range. ch2: -8 + 1 mV is
    // below E(-270 °C) = -6.458 mV: under range. ch4: 41.276 + 1 mV = 1025.74 °C: ok.
    let channels =
        "[ch0]\nopen = true\n[ch1]\nmillivolts = 60.0\n[ch2]\nmillivolts = -8.0\n[ch4]\nmillivolts = 41.276\n";
    std::fs::write(&scenario, channels).unwrap();
    let flash = flash_file("status.flash");
    let args = ["--listen", "127.0.0.1:0", "--scenario", scenario.to_str().unwrap()];
    let module = SimModule::start_with(BIN, &flash, &args);
    let mut ctx = connect(module.addr).await;
    write(&mut ctx, 0xDC, 0xF7).await; // channel 3 disabled

    // Values 40001-40008, status 40225-40232 (0 ok, 1 open, 2 over, 3 under, 4 disabled).
    let s = read_until(&mut ctx, 0xE0, 8, |s| s[..5] == [1, 2, 3, 4, 0]).await;
    let v = read(&mut ctx, 0, 8).await.unwrap();
    eprintln!("values {v:04x?} status {s:?}");
    assert_eq!(v[..4], [0xFFFF, 0xFFFF, 0x0000, 0x0000], "open upscale, over, under, disabled");
    // Spec §2.3: round((1025.74 + 250) / 1650 * 65535) = 50670.
    assert!((i32::from(v[4]) - 50670).abs() <= 2, "ch4 1025.74 °C: {:04x}", v[4]);

    // A front-end fault: every enabled channel 5; a cold-junction fault: thermocouples 6 (an
    // open input still says open).
    std::fs::write(&scenario, format!("{channels}[frontend]\nfault = true\n")).unwrap();
    let s = read_until(&mut ctx, 0xE0, 8, |s| s[..5] == [5, 5, 5, 4, 5]).await;
    eprintln!("front-end fault: status {s:?}");
    std::fs::write(&scenario, format!("{channels}[cjc]\nfault = true\n")).unwrap();
    let s = read_until(&mut ctx, 0xE0, 8, |s| s[..5] == [1, 6, 6, 4, 6]).await;
    eprintln!("cold-junction fault: status {s:?}");
    std::fs::write(&scenario, channels).unwrap();
    read_until(&mut ctx, 0xE0, 5, |s| s == [1, 2, 3, 4, 0]).await;

    // Open-input value: downscale reads 0000h; only 0 and 1 are accepted; it persists.
    assert_eq!(read(&mut ctx, 0xE8, 1).await.unwrap(), [0], "factory: upscale");
    let bad = timeout(LIMIT, ctx.write_single_register(0xE8, 2)).await.unwrap().unwrap();
    assert_eq!(bad, Err(ExceptionCode::IllegalDataValue));
    write(&mut ctx, 0xE8, 1).await;
    read_until(&mut ctx, 0, 1, |v| v == [0x0000]).await;
    assert_eq!(read(&mut ctx, 0xE0, 1).await.unwrap(), [1], "still open");
    drop(ctx);
    module.kill();
    let module = SimModule::start_with(BIN, &flash_file_keep("status.flash"), &args);
    let mut ctx = connect(module.addr).await;
    assert_eq!(read(&mut ctx, 0xE8, 1).await.unwrap(), [1], "persisted");
    read_until(&mut ctx, 0, 1, |v| v == [0x0000]).await;
    write(&mut ctx, 0xE8, 0).await;
    read_until(&mut ctx, 0, 1, |v| v == [0xFFFF]).await;
}
