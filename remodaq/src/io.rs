//! Reading, watching and configuring a module's I/O over Modbus/TCP (tokio-modbus).

use std::net::{SocketAddr, ToSocketAddrs};
use std::time::Duration;

use clap::{Subcommand, ValueEnum};
use remodaq_protocol::m8318::{
    self, ChannelStatus, InputType, Kind, REG_CJC_OFFSET, REG_ENABLE_MASK, REG_INPUT_TYPE, REG_OPEN_VALUE, REG_STATUS,
};
use remodaq_protocol::m8350::{self, wd_mode, DiMode as Mode, Point, PulseField, Word};
use remodaq_protocol::{diag, identity, words_low_first};
use serde::Serialize;
use tokio::time::timeout as within;
use tokio_modbus::client::{tcp, Client, Context};
use tokio_modbus::{ExceptionCode, Request, Response};

use crate::Error;

/// An I/O setting (`remodaq config MODULE ...`).
#[derive(Subcommand)]
pub enum Setting {
    /// 8318: input type of all channels (40201): a code (0F), or a thermocouple letter (K).
    Type { code: String },
    /// 8318: enabled channels (40221) as a bit mask, e.g. 0xFF or 0b101.
    Enable { mask: String },
    /// 8318: cold-junction offset (40216), °C, -50 to 50.
    CjcOffset {
        #[arg(allow_negative_numbers = true)]
        celsius: f64,
    },
    /// 8318: what an open (burnt-out) thermocouple reads (40233): upscale FFFFh (factory) or
    /// downscale 0000h.
    OpenValue { value: OpenValue },
    /// 8350: host watchdog (40305, 40307): a timeout in seconds (0.1 to 600), `off`, or
    /// `clear` to end the safe state (0 to 40308). When no feeding request arrives in time,
    /// the outputs go to their safe levels.
    Watchdog {
        /// Seconds, `off` or `clear`.
        #[arg(value_name = "SECONDS|off|clear")]
        seconds: String,
        /// Only write requests feed the watchdog (default: any request).
        #[arg(long)]
        writes_only: bool,
        /// The next feeding request ends the safe state (default: only `watchdog clear`).
        #[arg(long)]
        auto_clear: bool,
    },
    /// 8350: output levels in the watchdog's safe state (40306), bit N = DO N, e.g. 0b000011.
    Safe { levels: String },
    /// 8350: output levels after a power-up or restart (40309), bit N = DO N.
    PowerOn { levels: String },
    /// 8350: mode of input N (40257 + N).
    DiMode { channel: u16, mode: DiMode },
    /// 8350: mode of output N (40273 + N).
    DoMode { channel: u16, mode: DoMode },
    /// 8350: pulse train of output N (40025.., 40037.., 40049..): widths in ms (0.1 ms steps).
    Pulse {
        channel: u16,
        #[arg(long)]
        low_ms: f64,
        #[arg(long)]
        high_ms: f64,
        /// Pulses per train; 0 = continuous.
        #[arg(long, default_value_t = 0)]
        count: u32,
    },
    /// 8350: add pulses to output N's running train (40061 + 2N).
    Extra { channel: u16, pulses: u32 },
    /// 8350: start, stop or clear input N's counter (bits 00033 + 4N, 00034 + 4N).
    Counter { channel: u16, action: CounterAction },
    /// 8350: clear input N's latch flag (bit 00036 + 4N).
    LatchClear { channel: u16 },
    /// 8350: set output N (bit 00017 + N); in pulse mode `on` starts the train, `off` stops it.
    Do { channel: u16, state: OnOff },
    /// Either module: write one holding register, by its 4X number (40201) or PDU address
    /// (0xC8), for what the commands above do not cover.
    Register { address: String, value: String },
}

#[derive(Clone, Copy, ValueEnum)]
pub enum DiMode {
    Normal,
    Counter,
    LatchRising,
    LatchFalling,
    Frequency,
}

impl From<DiMode> for Mode {
    fn from(m: DiMode) -> Mode {
        match m {
            DiMode::Normal => Mode::Normal,
            DiMode::Counter => Mode::Counter,
            DiMode::LatchRising => Mode::LatchRising,
            DiMode::LatchFalling => Mode::LatchFalling,
            DiMode::Frequency => Mode::Frequency,
        }
    }
}

#[derive(Clone, Copy, ValueEnum)]
pub enum OpenValue {
    /// FFFFh (factory).
    Upscale,
    /// 0000h.
    Downscale,
}

/// Where `read` and `watch` ask the module whether its writes are restricted.
#[derive(clap::Args)]
pub struct DiscoveryAt {
    /// The module's discovery service (default: the module's address, port 8300).
    #[arg(long, value_name = "ADDR:PORT")]
    discovery: Option<SocketAddr>,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum DoMode {
    Normal,
    Pulse,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum CounterAction {
    Start,
    Stop,
    Clear,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum OnOff {
    On,
    Off,
}

const DI_MODES: [&str; 5] = ["normal", "counter", "latch-rising", "latch-falling", "frequency"];

/// The 4X address of an 8350 register point.
fn reg(point: Point) -> u16 {
    point.addr().1
}

/// The 0X address of an 8350 bit point.
fn bit(point: Point) -> u16 {
    point.addr().1
}

fn exception(e: ExceptionCode) -> Error {
    let meaning = match e {
        ExceptionCode::IllegalFunction => {
            "01 illegal function: the module does not support this request, or does not let this PC write (see `remodaq access`)"
        }
        ExceptionCode::IllegalDataAddress => "02 illegal data address: not mapped for this access on this module",
        ExceptionCode::IllegalDataValue => "03 illegal data value: the module does not accept this value",
        ExceptionCode::ServerDeviceFailure => {
            "04 server device failure: the setting could not be stored, or the outputs are held in the safe state (host watchdog tripped: `config MODULE watchdog clear`)"
        }
        _ => "unexpected exception",
    };
    Error::Exception(format!("the module answered exception {meaning}"))
}

/// A module's Modbus/TCP connection.
struct Module {
    ctx: Context,
    addr: SocketAddr,
    timeout: Duration,
    model: u16,
}

fn resolve(module: &str) -> Result<SocketAddr, Error> {
    let with_port =
        if module.contains(':') { module.to_string() } else { format!("{module}:{}", remodaq_protocol::MODBUS_PORT) };
    with_port
        .to_socket_addrs()
        .map_err(|e| Error::Other(format!("`{module}`: {e}")))?
        .next()
        .ok_or_else(|| Error::Other(format!("`{module}`: no address")))
}

impl Module {
    async fn connect(module: &str, timeout: Duration) -> Result<Self, Error> {
        let addr = resolve(module)?;
        let ctx = within(timeout, tcp::connect(addr))
            .await
            .map_err(|_| Error::Timeout(format!("no connection to {addr} within {:.1} s", timeout.as_secs_f64())))?
            .map_err(|e| Error::Other(format!("cannot connect to {addr}: {e}")))?;
        let mut m = Self { ctx, addr, timeout, model: 0 };
        m.model = m.reg(identity::REG_NAME).await?;
        if m.model != m8318::MODULE_NAME && m.model != m8350::MODULE_NAME {
            return Err(Error::Other(format!("{addr} is not a RemoDAQ-8318 or -8350 (40211 reads {:04X})", m.model)));
        }
        Ok(m)
    }

    fn late(&self) -> Error {
        Error::Timeout(format!("{} did not answer within {:.1} s", self.addr, self.timeout.as_secs_f64()))
    }

    /// The outcome of one request: no answer in time, a reply that does not fit it (another
    /// transaction or function, undecodable, the connection dropped), an exception, or the
    /// value.
    fn outcome<T>(&self, answer: Result<tokio_modbus::Result<T>, tokio::time::error::Elapsed>) -> Result<T, Error> {
        let reply = answer.map_err(|_| self.late())?;
        match reply {
            Ok(result) => result.map_err(exception),
            Err(tokio_modbus::Error::Protocol(e)) => Err(Error::Reply(format!("{}: {e}", self.addr))),
            Err(tokio_modbus::Error::Transport(e)) if e.kind() == std::io::ErrorKind::InvalidData => {
                Err(Error::Reply(format!("{}: not a Modbus/TCP reply ({e})", self.addr)))
            }
            Err(tokio_modbus::Error::Transport(e)) => Err(Error::Other(format!("{}: {e}", self.addr))),
        }
    }

    /// One request through tokio-modbus's checked `call` (it rejects another transaction or
    /// function); the caller checks that the response fits the request.
    async fn call(&mut self, request: Request<'_>) -> Result<Response, Error> {
        let answer = within(self.timeout, self.ctx.call(request)).await;
        self.outcome(answer)
    }

    fn misfit(&self, what: String) -> Error {
        Error::Reply(format!("{}: {what}", self.addr))
    }

    async fn regs(&mut self, addr: u16, n: u16) -> Result<Vec<u16>, Error> {
        match self.call(Request::ReadHoldingRegisters(addr, n)).await? {
            Response::ReadHoldingRegisters(words) if words.len() == usize::from(n) => Ok(words),
            Response::ReadHoldingRegisters(words) => {
                Err(self.misfit(format!("{} registers in the reply to a read of {n}", words.len())))
            }
            other => Err(self.misfit(format!("{other:?} in reply to a read of registers"))),
        }
    }

    async fn reg(&mut self, addr: u16) -> Result<u16, Error> {
        Ok(self.regs(addr, 1).await?[0])
    }

    async fn bits(&mut self, addr: u16, n: u16) -> Result<Vec<bool>, Error> {
        match self.call(Request::ReadCoils(addr, n)).await? {
            // Bits come in whole bytes: the reply carries up to 7 padding bits.
            Response::ReadCoils(mut bits) if bits.len() >= usize::from(n) && bits.len() < usize::from(n) + 8 => {
                bits.truncate(usize::from(n));
                Ok(bits)
            }
            Response::ReadCoils(bits) => Err(self.misfit(format!("{} bits in the reply to a read of {n}", bits.len()))),
            other => Err(self.misfit(format!("{other:?} in reply to a read of bits"))),
        }
    }

    async fn write_regs(&mut self, addr: u16, values: &[u16]) -> Result<(), Error> {
        let n = values.len() as u16;
        match self.call(Request::WriteMultipleRegisters(addr, values.into())).await? {
            Response::WriteMultipleRegisters(a, q) if (a, q) == (addr, n) => Ok(()),
            other => Err(self.misfit(format!("{other:?} in reply to a write of {n} registers at {addr:#06x}"))),
        }
    }

    async fn write_bit(&mut self, addr: u16, on: bool) -> Result<(), Error> {
        match self.call(Request::WriteSingleCoil(addr, on)).await? {
            Response::WriteSingleCoil(a, v) if (a, v) == (addr, on) => Ok(()),
            other => Err(self.misfit(format!("{other:?} in reply to a write of bit {addr:#06x}"))),
        }
    }

    fn expect(&self, model: u16) -> Result<(), Error> {
        if self.model == model {
            Ok(())
        } else {
            Err(Error::Other(format!(
                "this setting is for a RemoDAQ-{model:04X}; {} is a RemoDAQ-{:04X}",
                self.addr, self.model
            )))
        }
    }
}

/// One reading of an 8318.
#[derive(Serialize)]
struct Analog {
    model: &'static str,
    input_type: String,
    type_code: String,
    unit: &'static str,
    cold_junction_c: Option<f64>,
    cjc_offset_c: f64,
    /// What an open input reads: "upscale" (FFFFh) or "downscale" (0000h).
    open_value: &'static str,
    channels: Vec<AnalogChannel>,
    diagnostics: Diagnostics,
    /// Whether the module's write allow-list restricts writes (`null`: unknown).
    writes_restricted: Option<bool>,
}

/// The diagnostics registers (extensions §1).
#[derive(Serialize)]
struct Diagnostics {
    /// Module status: the names of the bits set.
    status: Vec<&'static str>,
    status_raw: u16,
    uptime_s: u32,
    reset_cause: &'static str,
    connections: u16,
    requests: u32,
    exceptions: u16,
    security: SecurityEvents,
}

/// The security event registers (docs/diagnostics.md).
#[derive(Serialize)]
struct SecurityEvents {
    factory_password: bool,
    auth_failures: u16,
    last_failed_source: Option<std::net::Ipv4Addr>,
    budget_refusals: u16,
    access_refusals: u16,
    update_refusals: u16,
    update_key: String,
}

async fn read_diagnostics(m: &mut Module) -> Result<Diagnostics, Error> {
    let base = diag::REG_MODULE_STATUS;
    let r = m.regs(base, diag::REG_UPDATE_REFUSALS - base + 1).await?;
    let key = m.regs(diag::REG_UPDATE_KEY, 4).await?;
    let at = |reg: u16| r[usize::from(reg - base)];
    let status = at(diag::REG_MODULE_STATUS);
    let [a, b] = at(diag::REG_LAST_FAILED_SOURCE).to_be_bytes();
    let [c, d] = at(diag::REG_LAST_FAILED_SOURCE + 1).to_be_bytes();
    let source = std::net::Ipv4Addr::new(a, b, c, d);
    Ok(Diagnostics {
        status: diag::status::NAMES.iter().filter(|(bit, _)| status & bit != 0).map(|(_, name)| *name).collect(),
        status_raw: status,
        uptime_s: remodaq_protocol::u32_low_first(at(diag::REG_UPTIME), at(diag::REG_UPTIME + 1)),
        reset_cause: diag::reset_cause::name(at(diag::REG_RESET_CAUSE)),
        connections: at(diag::REG_CONNECTIONS),
        requests: remodaq_protocol::u32_low_first(at(diag::REG_REQUESTS), at(diag::REG_REQUESTS + 1)),
        exceptions: at(diag::REG_EXCEPTIONS),
        security: SecurityEvents {
            factory_password: at(diag::REG_SECURITY) & diag::security::FACTORY_PASSWORD != 0,
            auth_failures: at(diag::REG_AUTH_FAILURES),
            last_failed_source: (!source.is_unspecified()).then_some(source),
            budget_refusals: at(diag::REG_BUDGET_REFUSALS),
            access_refusals: at(diag::REG_ACCESS_REFUSALS),
            update_refusals: at(diag::REG_UPDATE_REFUSALS),
            update_key: key.iter().map(|w| format!("{w:04x}")).collect(),
        },
    })
}

fn print_diagnostics(d: &Diagnostics) {
    let status = if d.status.is_empty() { "ok".to_string() } else { d.status.join(", ") };
    println!(
        "  module: {status}; up {} s, reset cause {}; {} client(s), {} requests, {} exceptions",
        d.uptime_s, d.reset_cause, d.connections, d.requests, d.exceptions
    );
    let e = &d.security;
    let last = e.last_failed_source.map_or(String::new(), |ip| format!(" (last from {ip})"));
    println!(
        "  security: {} failed authentication(s){last}, {} refused by the guessing budget, {} write(s) refused by \
         the allow-list, {} update(s) refused; update key {}",
        e.auth_failures, e.budget_refusals, e.access_refusals, e.update_refusals, e.update_key
    );
    if e.factory_password {
        println!("  security: the factory password is in force: set one (remodaq password --mac MAC)");
    }
}

#[derive(Serialize)]
struct AnalogChannel {
    channel: usize,
    enabled: bool,
    raw: u16,
    value: Option<f64>,
    status: &'static str,
}

fn type_name(t: &InputType) -> (String, &'static str, f64) {
    match t.kind {
        Kind::Thermocouple(tc) => (format!("thermocouple {}", tc.letter()), "°C", 1.0),
        Kind::Current => ("current ±20 mA".into(), "mA", 1.0),
        Kind::Voltage if t.hi >= 1000.0 => (format!("voltage ±{} V", t.hi / 1000.0), "V", 1000.0),
        Kind::Voltage => (format!("voltage ±{} mV", t.hi), "mV", 1.0),
    }
}

async fn read_analog(m: &mut Module) -> Result<Analog, Error> {
    // Channels 0-7 and the cold junction: 40001-40009 in one request.
    let values = m.regs(m8318::REG_VALUE, m8318::Reg::Cjc.addr() - m8318::REG_VALUE + 1).await?;
    let code = m.reg(REG_INPUT_TYPE).await?;
    let offset = m.reg(REG_CJC_OFFSET).await? as i16;
    let enabled = m.reg(REG_ENABLE_MASK).await?;
    // 40225-40233: channel statuses and the open-input value.
    let status = m.regs(REG_STATUS, REG_OPEN_VALUE - REG_STATUS + 1).await?;
    let input =
        InputType::from_code(code as u8).ok_or_else(|| Error::Other(format!("unknown input type {code:02X}")))?;
    let (name, unit, divisor) = type_name(&input);
    let channels = (0..m8318::CHANNELS)
        .map(|ch| {
            let raw = values[ch];
            let on = enabled & (1 << ch) != 0;
            let state = ChannelStatus::from_register(status[ch]);
            let value =
                (state == Some(ChannelStatus::Ok)).then(|| (input.value(raw) / divisor * 1000.0).round() / 1000.0);
            AnalogChannel { channel: ch, enabled: on, raw, value, status: state.map_or("unknown", ChannelStatus::name) }
        })
        .collect();
    Ok(Analog {
        model: m8318::MODEL,
        input_type: name,
        type_code: format!("{code:02X}"),
        unit,
        // 7FFFh: the cold junction could not be read.
        cold_junction_c: match values[usize::from(m8318::Reg::Cjc.addr() - m8318::REG_VALUE)] {
            0x7FFF => None,
            raw => Some(f64::from(raw as i16) / 100.0),
        },
        cjc_offset_c: f64::from(offset) / 100.0,
        open_value: if status[m8318::CHANNELS] == 1 { "downscale" } else { "upscale" },
        channels,
        diagnostics: read_diagnostics(m).await?,
        writes_restricted: None,
    })
}

/// One reading of an 8350.
#[derive(Serialize)]
struct Digital {
    model: &'static str,
    inputs: Vec<Input>,
    outputs: Vec<Output>,
    watchdog: Watchdog,
    diagnostics: Diagnostics,
    /// Whether the module's write allow-list restricts writes (`null`: unknown).
    writes_restricted: Option<bool>,
}

/// The host watchdog (extensions §3).
#[derive(Serialize)]
struct Watchdog {
    /// Timeout, s; 0: off.
    timeout_s: f64,
    writes_only: bool,
    auto_clear: bool,
    /// The outputs are held in the safe state.
    tripped: bool,
    /// Safe levels, bit n = DOn.
    safe: u16,
    /// Power-on levels, bit n = DOn.
    power_on: u16,
}

#[derive(Serialize)]
struct Input {
    channel: usize,
    state: bool,
    mode: &'static str,
    /// Counter value, or frequency (Hz) in frequency mode.
    value: u32,
    counter_running: bool,
    overflow: bool,
    latch: bool,
}

#[derive(Serialize)]
struct Output {
    channel: usize,
    state: bool,
    mode: &'static str,
    low_ms: f64,
    high_ms: f64,
    count: u32,
}

fn pairs(words: &[u16]) -> Vec<u32> {
    words.chunks_exact(2).map(|p| remodaq_protocol::u32_low_first(p[0], p[1])).collect()
}

async fn read_digital(m: &mut Module) -> Result<Digital, Error> {
    const DI: u16 = m8350::DI_CHANNELS as u16;
    const DO: u16 = m8350::DO_CHANNELS as u16;
    let states = m.reg(reg(Point::AllDi)).await?;
    let counters = pairs(&m.regs(reg(Point::Counter(0, Word::Low)), 2 * DI).await?);
    let pulses = pairs(&m.regs(reg(Point::Pulse(PulseField::Low, 0, Word::Low)), 6 * DO).await?);
    let di_modes = m.regs(reg(Point::DiMode(0)), DI).await?;
    let do_modes = m.regs(reg(Point::DoMode(0)), DO).await?;
    let dos = m.bits(bit(Point::Do(0)), DO).await?;
    // Reading the overflow and latch flags clears them (the module's documented behaviour).
    let flags = m.bits(bit(Point::CounterRun(0)), 4 * DI).await?;
    let inputs = (0..m8350::DI_CHANNELS)
        .map(|n| Input {
            channel: n,
            state: states & (1 << n) != 0,
            mode: DI_MODES.get(usize::from(di_modes[n])).copied().unwrap_or("unknown"),
            value: counters[n],
            counter_running: flags[4 * n],
            overflow: flags[4 * n + 2],
            latch: flags[4 * n + 3],
        })
        .collect();
    let outputs = (0..m8350::DO_CHANNELS)
        .map(|n| Output {
            channel: n,
            state: dos[n],
            mode: if do_modes[n] == 1 { "pulse" } else { "normal" },
            low_ms: f64::from(pulses[n]) / 10.0,
            high_ms: f64::from(pulses[6 + n]) / 10.0,
            count: pulses[12 + n],
        })
        .collect();
    let w = m.regs(m8350::REG_WD_TIMEOUT, m8350::REG_POWER_ON - m8350::REG_WD_TIMEOUT + 1).await?;
    let watchdog = Watchdog {
        timeout_s: f64::from(w[0]) / 10.0,
        safe: w[1],
        writes_only: w[2] & wd_mode::WRITES_ONLY != 0,
        auto_clear: w[2] & wd_mode::AUTO_CLEAR != 0,
        tripped: w[3] & 1 != 0,
        power_on: w[4],
    };
    let diagnostics = read_diagnostics(m).await?;
    Ok(Digital { model: m8350::MODEL, inputs, outputs, watchdog, diagnostics, writes_restricted: None })
}

/// Asks the module's discovery service whether its writes are restricted (`None`: no answer).
async fn writes_restricted(addr: SocketAddr, timeout: Duration, at: &DiscoveryAt) -> Option<bool> {
    let to = at.discovery.unwrap_or(SocketAddr::new(addr.ip(), remodaq_protocol::discovery::PORT));
    let found = crate::lan::find(to, None, timeout.min(Duration::from_millis(500))).await.ok()?;
    // The module that serves this Modbus port (several simulated modules may share a PC).
    found.iter().find(|f| f.modbus_port == addr.port())?.writes_restricted
}

fn print_restricted(restricted: Option<bool>) {
    match restricted {
        Some(true) => println!("  writes: restricted to the allow-list (`remodaq access show`)"),
        Some(false) => println!("  writes: allowed from any client"),
        None => println!("  writes: restriction unknown (no answer from the discovery service)"),
    }
}

async fn read_once(m: &mut Module, at: &DiscoveryAt, json: bool) -> Result<(), Error> {
    let restricted = writes_restricted(m.addr, m.timeout, at);
    if m.model == m8318::MODULE_NAME {
        let (a, restricted) = tokio::join!(read_analog(m), restricted);
        let a = Analog { writes_restricted: restricted, ..a? };
        if json {
            println!("{}", serde_json::to_string(&a).unwrap_or_default());
            return Ok(());
        }
        let cj = a.cold_junction_c.map_or("unknown".to_string(), |t| format!("{t:.2} °C"));
        println!(
            "{} at {}: {} (type {}), cold junction {cj} (offset {:+.2})",
            a.model, m.addr, a.input_type, a.type_code, a.cjc_offset_c
        );
        print_diagnostics(&a.diagnostics);
        print_restricted(a.writes_restricted);
        println!(
            "  open input reads {}",
            if a.open_value == "downscale" { "0000h (downscale)" } else { "FFFFh (upscale)" }
        );
        for c in &a.channels {
            match c.value {
                Some(v) => println!("  ch{}  {:>10.3} {:<3}  ({:04X})", c.channel, v, a.unit, c.raw),
                None => println!("  ch{}  {:>14}  ({:04X})", c.channel, c.status, c.raw),
            }
        }
    } else {
        let (d, restricted) = tokio::join!(read_digital(m), restricted);
        let d = Digital { writes_restricted: restricted, ..d? };
        if json {
            println!("{}", serde_json::to_string(&d).unwrap_or_default());
            return Ok(());
        }
        println!("{} at {}", d.model, m.addr);
        print_diagnostics(&d.diagnostics);
        print_restricted(d.writes_restricted);
        let w = &d.watchdog;
        if w.timeout_s == 0.0 {
            println!("  host watchdog: off");
        } else {
            println!(
                "  host watchdog: {} s, fed by {}, cleared {}; {}",
                w.timeout_s,
                if w.writes_only { "writes" } else { "any request" },
                if w.auto_clear { "by the next feeding request" } else { "by `watchdog clear`" },
                if w.tripped { "TRIPPED: outputs in the safe state" } else { "not tripped" }
            );
        }
        println!("  safe levels {:06b}, power-on levels {:06b} (DO5..DO0)", w.safe, w.power_on);
        println!(
            "  {:<5} {:<5} {:<13} {:>12} {:<8} {:<8} {:<5}",
            "input", "state", "mode", "value", "counter", "overflow", "latch"
        );
        for i in &d.inputs {
            let value = match i.mode {
                "counter" => i.value.to_string(),
                "frequency" => format!("{} Hz", i.value),
                _ => "-".into(),
            };
            println!(
                "  DI{:<3} {:<5} {:<13} {:>12} {:<8} {:<8} {:<5}",
                i.channel,
                u8::from(i.state),
                i.mode,
                value,
                if i.counter_running { "running" } else { "stopped" },
                u8::from(i.overflow),
                u8::from(i.latch)
            );
        }
        println!("  {:<5} {:<5} {:<7} {:>9} {:>9} {:>7}", "output", "state", "mode", "low ms", "high ms", "count");
        for o in &d.outputs {
            println!(
                "  DO{:<4} {:<5} {:<7} {:>9.1} {:>9.1} {:>7}",
                o.channel,
                u8::from(o.state),
                o.mode,
                o.low_ms,
                o.high_ms,
                o.count
            );
        }
    }
    Ok(())
}

/// The module name and firmware version registers of a module, and its address.
pub async fn identity(module: &str, timeout: Duration) -> Result<(SocketAddr, u16, u16), Error> {
    let mut m = Module::connect(module, timeout).await?;
    let version = m.reg(identity::REG_VERSION).await?;
    Ok((m.addr, m.model, version))
}

/// `remodaq read`.
pub async fn read(module: &str, at: DiscoveryAt, timeout: Duration, json: bool) -> Result<(), Error> {
    let mut m = Module::connect(module, timeout).await?;
    read_once(&mut m, &at, json).await
}

/// `remodaq watch`: a reading every `interval` (JSON: one object per line).
pub async fn watch(
    module: &str,
    at: DiscoveryAt,
    timeout: Duration,
    interval: Duration,
    count: Option<u64>,
    json: bool,
) -> Result<(), Error> {
    let mut m = Module::connect(module, timeout).await?;
    let mut ticker = tokio::time::interval(interval);
    let mut done = 0u64;
    while count.is_none_or(|c| done < c) {
        ticker.tick().await;
        read_once(&mut m, &at, json).await?;
        done += 1;
    }
    Ok(())
}

fn parse_number(s: &str) -> Result<u32, Error> {
    let s = s.trim();
    let parsed = if let Some(h) = s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        u32::from_str_radix(h, 16)
    } else if let Some(b) = s.strip_prefix("0b") {
        u32::from_str_radix(b, 2)
    } else {
        s.parse()
    };
    parsed.map_err(|_| Error::Other(format!("`{s}` is not a number")))
}

fn type_code(s: &str) -> Result<u16, Error> {
    let letter = s.trim().to_ascii_uppercase();
    let by_letter = m8318::INPUT_TYPES.iter().find(|t| t.thermocouple().is_some_and(|tc| tc.letter() == letter));
    if let Some(t) = by_letter {
        return Ok(u16::from(t.code));
    }
    let code = u16::from_str_radix(letter.trim_start_matches("0X"), 16)
        .map_err(|_| Error::Other(format!("`{s}` is not a type code")))?;
    InputType::from_code(code as u8)
        .filter(|_| code <= 0xFF)
        .map(|_| code)
        .ok_or_else(|| Error::Other(format!("{code:02X} is not an input type code (00-06, 0E-18)")))
}

/// Output levels, bit n = DOn (6 bits).
fn output_levels(s: &str) -> Result<u16, Error> {
    match parse_number(s)? {
        v if v < 1 << m8350::DO_CHANNELS => Ok(v as u16),
        _ => Err(Error::Other(format!("`{s}`: the output levels have 6 bits (0 to 0b111111)"))),
    }
}

fn channel(n: u16, count: usize) -> Result<u8, Error> {
    match u8::try_from(n) {
        Ok(ch) if usize::from(n) < count => Ok(ch),
        _ => Err(Error::Other(format!("channel {n} does not exist (0..{})", count - 1))),
    }
}

fn ticks(ms: f64) -> Result<u32, Error> {
    let t = (ms * 10.0).round();
    if (1.0..=f64::from(u32::MAX)).contains(&t) {
        Ok(t as u32)
    } else {
        Err(Error::Other(format!("{ms} ms is not a width (0.1 ms or more)")))
    }
}

/// `remodaq config`.
pub async fn config(module: &str, setting: Setting, timeout: Duration, json: bool) -> Result<(), Error> {
    let mut m = Module::connect(module, timeout).await?;
    let done = match setting {
        Setting::Type { code } => {
            m.expect(m8318::MODULE_NAME)?;
            let code = type_code(&code)?;
            m.write_regs(REG_INPUT_TYPE, &[code]).await?;
            format!("input type {code:02X}")
        }
        Setting::Enable { mask } => {
            m.expect(m8318::MODULE_NAME)?;
            let mask = parse_number(&mask)?;
            if mask > 0xFF {
                return Err(Error::Other("the enable mask has 8 bits (0x00 to 0xFF)".into()));
            }
            m.write_regs(REG_ENABLE_MASK, &[mask as u16]).await?;
            format!("enabled channels {mask:#04x}")
        }
        Setting::CjcOffset { celsius } => {
            m.expect(m8318::MODULE_NAME)?;
            let hundredths = (celsius * 100.0).round();
            let limit = f64::from(m8318::CJC_OFFSET_LIMIT);
            if !(-limit..=limit).contains(&hundredths) {
                return Err(Error::Other("the CJC offset is -50.00 to 50.00 °C".into()));
            }
            m.write_regs(REG_CJC_OFFSET, &[m8318::cjc_offset_to_register(hundredths as i16)]).await?;
            format!("CJC offset {:+.2} °C", hundredths / 100.0)
        }
        Setting::OpenValue { value } => {
            m.expect(m8318::MODULE_NAME)?;
            let downscale = matches!(value, OpenValue::Downscale);
            m.write_regs(REG_OPEN_VALUE, &[u16::from(downscale)]).await?;
            format!("open inputs read {}", if downscale { "0000h (downscale)" } else { "FFFFh (upscale)" })
        }
        Setting::Watchdog { seconds, writes_only, auto_clear } => {
            m.expect(m8350::MODULE_NAME)?;
            match seconds.trim() {
                "clear" => {
                    m.write_regs(m8350::REG_WD_STATUS, &[0]).await?;
                    "host watchdog cleared: outputs keep their safe levels until written".to_string()
                }
                t => {
                    let tenths = if t == "off" {
                        0.0
                    } else {
                        let s: f64 =
                            t.parse().map_err(|_| Error::Other(format!("`{t}` is not seconds, off or clear")))?;
                        (s * 10.0).round()
                    };
                    if !(0.0..=f64::from(m8350::WD_TIMEOUT_MAX)).contains(&tenths) || (t != "off" && tenths < 1.0) {
                        return Err(Error::Other("the watchdog timeout is 0.1 to 600 s, or off".into()));
                    }
                    let mode = if writes_only { wd_mode::WRITES_ONLY } else { 0 }
                        | if auto_clear { wd_mode::AUTO_CLEAR } else { 0 };
                    m.write_regs(m8350::REG_WD_MODE, &[mode]).await?;
                    m.write_regs(m8350::REG_WD_TIMEOUT, &[tenths as u16]).await?;
                    if tenths == 0.0 {
                        "host watchdog off".to_string()
                    } else {
                        format!(
                            "host watchdog {} s, fed by {}, cleared {}",
                            tenths / 10.0,
                            if writes_only { "writes" } else { "any request" },
                            if auto_clear { "automatically" } else { "by `watchdog clear`" }
                        )
                    }
                }
            }
        }
        Setting::Safe { levels } => {
            m.expect(m8350::MODULE_NAME)?;
            let v = output_levels(&levels)?;
            m.write_regs(m8350::REG_SAFE_VALUES, &[v]).await?;
            format!("safe levels {v:06b} (DO5..DO0)")
        }
        Setting::PowerOn { levels } => {
            m.expect(m8350::MODULE_NAME)?;
            let v = output_levels(&levels)?;
            m.write_regs(m8350::REG_POWER_ON, &[v]).await?;
            format!("power-on levels {v:06b} (DO5..DO0)")
        }
        Setting::DiMode { channel: n, mode } => {
            m.expect(m8350::MODULE_NAME)?;
            let n = channel(n, m8350::DI_CHANNELS)?;
            m.write_regs(reg(Point::DiMode(n)), &[Mode::from(mode) as u16]).await?;
            format!("DI{n} mode {}", DI_MODES[mode as usize])
        }
        Setting::DoMode { channel: n, mode } => {
            m.expect(m8350::MODULE_NAME)?;
            let n = channel(n, m8350::DO_CHANNELS)?;
            m.write_regs(reg(Point::DoMode(n)), &[mode as u16]).await?;
            format!("DO{n} mode {}", if matches!(mode, DoMode::Pulse) { "pulse" } else { "normal" })
        }
        Setting::Pulse { channel: n, low_ms, high_ms, count } => {
            m.expect(m8350::MODULE_NAME)?;
            let n = channel(n, m8350::DO_CHANNELS)?;
            let (low, high) = (ticks(low_ms)?, ticks(high_ms)?);
            for (field, value) in [(PulseField::Low, low), (PulseField::High, high), (PulseField::Count, count)] {
                m.write_regs(reg(Point::Pulse(field, n, Word::Low)), &words_low_first(value)).await?;
            }
            format!("DO{n} pulses: low {low_ms} ms, high {high_ms} ms, count {count}")
        }
        Setting::Extra { channel: n, pulses } => {
            m.expect(m8350::MODULE_NAME)?;
            let n = channel(n, m8350::DO_CHANNELS)?;
            m.write_regs(reg(Point::Pulse(PulseField::Extra, n, Word::Low)), &words_low_first(pulses)).await?;
            format!("DO{n}: {pulses} extra pulses")
        }
        Setting::Counter { channel: n, action } => {
            m.expect(m8350::MODULE_NAME)?;
            let n = channel(n, m8350::DI_CHANNELS)?;
            match action {
                CounterAction::Start => m.write_bit(bit(Point::CounterRun(n)), true).await?,
                CounterAction::Stop => m.write_bit(bit(Point::CounterRun(n)), false).await?,
                CounterAction::Clear => m.write_bit(bit(Point::CounterClear(n)), true).await?,
            }
            format!("DI{n} counter {}", ["started", "stopped", "cleared"][action as usize])
        }
        Setting::LatchClear { channel: n } => {
            m.expect(m8350::MODULE_NAME)?;
            let n = channel(n, m8350::DI_CHANNELS)?;
            m.write_bit(bit(Point::Latch(n)), false).await?;
            format!("DI{n} latch cleared")
        }
        Setting::Register { address, value } => {
            let a = parse_number(&address)?;
            let pdu = if (40001..=105536).contains(&a) { a - 40001 } else { a };
            let pdu = u16::try_from(pdu).map_err(|_| Error::Other(format!("`{address}` is not a register")))?;
            let v = u16::try_from(parse_number(&value)?)
                .map_err(|_| Error::Other(format!("`{value}` does not fit 16 bits")))?;
            m.write_regs(pdu, &[v]).await?;
            format!("register {} ({pdu:#06x}) = {v:#06x}", u32::from(pdu) + 40001)
        }
        Setting::Do { channel: n, state } => {
            m.expect(m8350::MODULE_NAME)?;
            let n = channel(n, m8350::DO_CHANNELS)?;
            let on = matches!(state, OnOff::On);
            m.write_bit(bit(Point::Do(n)), on).await?;
            format!("DO{n} {}", if on { "on" } else { "off" })
        }
    };
    if json {
        println!("{}", serde_json::json!({ "module": m.addr.to_string(), "status": "ok", "message": done }));
    } else {
        println!("{}: {done}", m.addr);
    }
    Ok(())
}
