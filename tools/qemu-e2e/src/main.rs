//! Boots a firmware image in QEMU (mps2-an386, LAN9118 on QEMU's user network with the Modbus
//! port forwarded to a local port) and checks it through tokio-modbus: identity registers, live
//! values, a setting written and read back, 8 clients at once. Every wait is bounded; QEMU is
//! killed by its PID at the end. Prints one `qemu-<model>: N passed, N failed` line.
//!
//! `qemu-e2e 8318 IMAGE` or `qemu-e2e 8350 IMAGE` (scripts/qemu-test builds the images).

use std::net::{SocketAddr, TcpListener};
use std::process::{Child, Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

use remodaq_8318::input::InputType;
use remodaq_8318::thermocouple::{Inverse, TcType};
use tokio::time::{sleep, timeout};
use tokio_modbus::client::{tcp, Context, Reader, Writer};

const STEP: Duration = Duration::from_secs(5);
const BOOT: Duration = Duration::from_secs(90);

struct Qemu(Child);

impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start_qemu(image: &str, port: u16) -> Result<Qemu, String> {
    let log = std::fs::File::create(format!("{image}.qemu.log")).map_err(|e| e.to_string())?;
    let child = Command::new("qemu-system-arm")
        .args(["-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "null"])
        .args(["-semihosting-config", "enable=on,target=native"])
        .args(["-nic", &format!("user,model=lan9118,hostfwd=tcp:127.0.0.1:{port}-:8000")])
        .args(["-kernel", image])
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
            if timeout(Duration::from_secs(2), ctx.read_holding_registers(0xD2, 1))
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

impl Report {
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

async fn live_values(model: u16, ctx: &mut Context) -> Result<(), String> {
    if model == 0x8318 {
        // ch0: type K at 100 °C with the cold junction at 25 °C; 40009 = 25.00 °C.
        let v = regs(ctx, 0, 9).await?;
        let Inverse::Celsius(t) = TcType::K.temperature_c(4.096 - 1.000 + TcType::K.emf_mv(25.0).unwrap_or(1.0)) else {
            return Err("reference".into());
        };
        let want = InputType::from_code(0x0F).map(|k| k.raw(t)).unwrap_or(0);
        if v[0].abs_diff(want) > 2 || v[8] != 2500 || v[3] != 0xFFFF {
            return Err(format!("registers {v:04x?}, expected ch0 {want:04x}, 40009 09c4, ch3 ffff"));
        }
        // ch4 ramps: it moves.
        let before = v[4];
        sleep(Duration::from_millis(1500)).await;
        let after = regs(ctx, 4, 1).await?[0];
        if after == before {
            return Err(format!("ch4 stayed at {before:04x}"));
        }
    } else {
        // DI3 is high; DI0's 1 kHz square wave counted in counter mode.
        let di = regs(ctx, 0x12C, 1).await?[0];
        if di & 0b1000 == 0 {
            return Err(format!("all-DI register {di:04x}: DI3 should be high"));
        }
        write(ctx, 0x100, &[1]).await?;
        let c0 = regs(ctx, 0, 2).await?;
        let t0 = Instant::now();
        sleep(Duration::from_millis(2000)).await;
        let c1 = regs(ctx, 0, 2).await?;
        let count = |w: &[u16]| u32::from(w[0]) | u32::from(w[1]) << 16;
        let rate = f64::from(count(&c1).wrapping_sub(count(&c0))) / t0.elapsed().as_secs_f64();
        if !(700.0..1300.0).contains(&rate) {
            return Err(format!("DI0 counted {rate:.0}/s, expected about 1000"));
        }
    }
    Ok(())
}

async fn setting_round_trip(model: u16, ctx: &mut Context) -> Result<(), String> {
    let (addr, values): (u16, &[u16]) = if model == 0x8318 { (0xC8, &[0x0E]) } else { (0x18, &[25, 0]) };
    write(ctx, addr, values).await?;
    let back = regs(ctx, addr, values.len() as u16).await?;
    if back != values {
        return Err(format!("wrote {values:x?} to {addr:#x}, read {back:x?}"));
    }
    Ok(())
}

async fn eight_clients(addr: SocketAddr, model: u16) -> Result<(), String> {
    let mut tasks = Vec::new();
    for client in 0..8 {
        tasks.push(tokio::spawn(async move {
            let mut ctx = connect(addr).await?;
            for _ in 0..20 {
                let v = regs(&mut ctx, 0xD2, 1).await?;
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
    let port = TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).map(|a| a.port()).unwrap_or(18000);
    let addr = SocketAddr::from(([127, 0, 0, 1], port));
    let qemu = match start_qemu(image, port) {
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
        let (n, v) = (regs(&mut ctx, 0xD2, 1).await?, regs(&mut ctx, 0xD4, 1).await?);
        if n == [name] && v == [0xA100] {
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
    drop(qemu);
    report
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    let (Some(model), Some(image)) = (args.get(1), args.get(2)) else {
        eprintln!("usage: qemu-e2e 8318|8350 IMAGE");
        return ExitCode::from(2);
    };
    let Ok(runtime) = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build() else {
        return ExitCode::from(1);
    };
    let report = runtime.block_on(run(model, image));
    println!("qemu-{}: {} passed, {} failed", report.model, report.passed, report.failed);
    if report.failed == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}
