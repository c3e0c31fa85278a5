//! Reading, watching and configuring a module's I/O over Modbus/TCP (tokio-modbus).

use std::net::SocketAddr;
use std::time::Duration;

use clap::{Subcommand, ValueEnum};
use remodaq_protocol::m8318::{self, InputType};
use remodaq_protocol::m8350::{self, DiMode as Mode};

use remodaq_client::modbus::Module;
use remodaq_client::reading::{read_analog, read_digital, Analog, Diagnostics, Digital};
use remodaq_client::settings::{self, CounterAction as Action, Write};
use remodaq_client::Error;

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

/// Asks the module's discovery service whether its writes are restricted (`None`: no answer).
async fn writes_restricted(addr: SocketAddr, timeout: Duration, at: &DiscoveryAt) -> Option<bool> {
    let to = at.discovery.unwrap_or(SocketAddr::new(addr.ip(), remodaq_protocol::discovery::PORT));
    let found = remodaq_client::lan::find(to, None, timeout.min(Duration::from_millis(500))).await.ok()?;
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
        let (d, restricted) = tokio::join!(read_digital(m, true), restricted);
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
    let write = match setting {
        Setting::Type { code } => Write::InputType(type_code(&code)?),
        Setting::Enable { mask } => Write::Enable(
            u16::try_from(parse_number(&mask)?)
                .ok()
                .filter(|&m| m <= 0xFF)
                .ok_or_else(|| Error::Other("the enable mask has 8 bits (0x00 to 0xFF)".into()))?,
        ),
        Setting::CjcOffset { celsius } => {
            let hundredths = (celsius * 100.0).round();
            if !hundredths.is_finite() || hundredths.abs() > f64::from(m8318::CJC_OFFSET_LIMIT) {
                return Err(Error::Other("the CJC offset is -50.00 to 50.00 °C".into()));
            }
            Write::CjcOffset(hundredths as i32)
        }
        Setting::OpenValue { value } => Write::OpenDownscale(matches!(value, OpenValue::Downscale)),
        Setting::Watchdog { seconds, writes_only, auto_clear } => match seconds.trim() {
            "clear" => Write::WatchdogClear,
            t => {
                let tenths = if t == "off" {
                    0.0
                } else {
                    let s: f64 = t.parse().map_err(|_| Error::Other(format!("`{t}` is not seconds, off or clear")))?;
                    (s * 10.0).round()
                };
                if !(0.0..=f64::from(m8350::WD_TIMEOUT_MAX)).contains(&tenths) || (t != "off" && tenths < 1.0) {
                    return Err(Error::Other("the watchdog timeout is 0.1 to 600 s, or off".into()));
                }
                Write::Watchdog { tenths: tenths as u32, writes_only, auto_clear }
            }
        },
        Setting::Safe { levels } => Write::SafeLevels(output_levels(&levels)?),
        Setting::PowerOn { levels } => Write::PowerOnLevels(output_levels(&levels)?),
        Setting::DiMode { channel, mode } => Write::DiMode(channel, Mode::from(mode)),
        Setting::DoMode { channel, mode } => Write::DoPulseMode(channel, matches!(mode, DoMode::Pulse)),
        Setting::Pulse { channel, low_ms, high_ms, count } => {
            Write::Pulse { channel, low: ticks(low_ms)?, high: ticks(high_ms)?, count }
        }
        Setting::Extra { channel, pulses } => Write::Extra(channel, pulses),
        Setting::Counter { channel, action } => Write::Counter(
            channel,
            match action {
                CounterAction::Start => Action::Start,
                CounterAction::Stop => Action::Stop,
                CounterAction::Clear => Action::Clear,
            },
        ),
        Setting::LatchClear { channel } => Write::LatchClear(channel),
        Setting::Do { channel, state } => Write::Do(channel, matches!(state, OnOff::On)),
        Setting::Register { address, value } => {
            let a = parse_number(&address)?;
            let pdu = if (40001..=105536).contains(&a) { a - 40001 } else { a };
            let pdu = u16::try_from(pdu).map_err(|_| Error::Other(format!("`{address}` is not a register")))?;
            let v = u16::try_from(parse_number(&value)?)
                .map_err(|_| Error::Other(format!("`{value}` does not fit 16 bits")))?;
            Write::Register(pdu, v)
        }
    };
    let mut m = Module::connect(module, timeout).await?;
    let done = settings::apply(&mut m, &write).await?;
    if json {
        println!("{}", serde_json::json!({ "module": m.addr.to_string(), "status": "ok", "message": done }));
    } else {
        println!("{}: {done}", m.addr);
    }
    Ok(())
}
