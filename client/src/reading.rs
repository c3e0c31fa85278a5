//! One reading of a module over Modbus/TCP: an 8318's channels, an 8350's inputs and outputs,
//! and the diagnostics both have (extensions §1), as the CLI prints them and the utility shows
//! them.

use remodaq_protocol::diag;
use remodaq_protocol::m8318::{
    self, ChannelStatus, InputType, Kind, REG_CJC_OFFSET, REG_ENABLE_MASK, REG_INPUT_TYPE, REG_OPEN_VALUE, REG_STATUS,
};
use remodaq_protocol::m8350::{self, wd_mode, Point, PulseField, Word};
use serde::Serialize;

use crate::modbus::Module;
use crate::Error;

pub const DI_MODES: [&str; 5] = ["normal", "counter", "latch-rising", "latch-falling", "frequency"];

/// The 4X address of an 8350 register point.
pub fn reg(point: Point) -> u16 {
    point.addr().1
}

/// The 0X address of an 8350 bit point.
pub fn bit(point: Point) -> u16 {
    point.addr().1
}

/// One reading of an 8318.
#[derive(Serialize, Clone, Debug)]
pub struct Analog {
    pub model: &'static str,
    pub input_type: String,
    pub type_code: String,
    pub unit: &'static str,
    pub cold_junction_c: Option<f64>,
    pub cjc_offset_c: f64,
    /// What an open input reads: "upscale" (FFFFh) or "downscale" (0000h).
    pub open_value: &'static str,
    pub channels: Vec<AnalogChannel>,
    pub diagnostics: Diagnostics,
    /// Whether the module's write allow-list restricts writes (`null`: unknown).
    pub writes_restricted: Option<bool>,
}

/// The diagnostics registers (extensions §1).
#[derive(Serialize, Clone, Debug)]
pub struct Diagnostics {
    /// Module status: the names of the bits set.
    pub status: Vec<&'static str>,
    pub status_raw: u16,
    pub uptime_s: u32,
    pub reset_cause: &'static str,
    pub connections: u16,
    pub requests: u32,
    pub exceptions: u16,
    pub security: SecurityEvents,
}

/// The security event registers (docs/diagnostics.md).
#[derive(Serialize, Clone, Debug)]
pub struct SecurityEvents {
    pub factory_password: bool,
    pub auth_failures: u16,
    pub last_failed_source: Option<std::net::Ipv4Addr>,
    pub budget_refusals: u16,
    pub access_refusals: u16,
    pub update_refusals: u16,
    pub update_key: String,
}

pub async fn read_diagnostics(m: &mut Module) -> Result<Diagnostics, Error> {
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

#[derive(Serialize, Clone, Debug)]
pub struct AnalogChannel {
    pub channel: usize,
    pub enabled: bool,
    pub raw: u16,
    pub value: Option<f64>,
    pub status: &'static str,
}

pub fn type_name(t: &InputType) -> (String, &'static str, f64) {
    match t.kind {
        Kind::Thermocouple(tc) => (format!("thermocouple {}", tc.letter()), "°C", 1.0),
        Kind::Current => ("current ±20 mA".into(), "mA", 1.0),
        Kind::Voltage if t.hi >= 1000.0 => (format!("voltage ±{} V", t.hi / 1000.0), "V", 1000.0),
        Kind::Voltage => (format!("voltage ±{} mV", t.hi), "mV", 1.0),
    }
}

pub async fn read_analog(m: &mut Module) -> Result<Analog, Error> {
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
#[derive(Serialize, Clone, Debug)]
pub struct Digital {
    pub model: &'static str,
    pub inputs: Vec<Input>,
    pub outputs: Vec<Output>,
    pub watchdog: Watchdog,
    pub diagnostics: Diagnostics,
    /// Whether the module's write allow-list restricts writes (`null`: unknown).
    pub writes_restricted: Option<bool>,
}

/// The host watchdog (extensions §3).
#[derive(Serialize, Clone, Debug)]
pub struct Watchdog {
    /// Timeout, s; 0: off.
    pub timeout_s: f64,
    pub writes_only: bool,
    pub auto_clear: bool,
    /// The outputs are held in the safe state.
    pub tripped: bool,
    /// Safe levels, bit n = DOn.
    pub safe: u16,
    /// Power-on levels, bit n = DOn.
    pub power_on: u16,
}

#[derive(Serialize, Clone, Debug)]
pub struct Input {
    pub channel: usize,
    pub state: bool,
    pub mode: &'static str,
    /// Counter value, or frequency (Hz) in frequency mode.
    pub value: u32,
    pub counter_running: bool,
    pub overflow: bool,
    pub latch: bool,
}

#[derive(Serialize, Clone, Debug)]
pub struct Output {
    pub channel: usize,
    pub state: bool,
    pub mode: &'static str,
    pub low_ms: f64,
    pub high_ms: f64,
    pub count: u32,
}

pub fn pairs(words: &[u16]) -> Vec<u32> {
    words.chunks_exact(2).map(|p| remodaq_protocol::u32_low_first(p[0], p[1])).collect()
}

/// One reading of an 8350. With `flags`, the counters' run, overflow and latch flags too:
/// reading the overflow and latch flags clears them in the module, so a reader that does not
/// show them (a window's background poll) leaves them for the one that does.
pub async fn read_digital(m: &mut Module, flags: bool) -> Result<Digital, Error> {
    const DI: u16 = m8350::DI_CHANNELS as u16;
    const DO: u16 = m8350::DO_CHANNELS as u16;
    let states = m.reg(reg(Point::AllDi)).await?;
    let counters = pairs(&m.regs(reg(Point::Counter(0, Word::Low)), 2 * DI).await?);
    let pulses = pairs(&m.regs(reg(Point::Pulse(PulseField::Low, 0, Word::Low)), 6 * DO).await?);
    let di_modes = m.regs(reg(Point::DiMode(0)), DI).await?;
    let do_modes = m.regs(reg(Point::DoMode(0)), DO).await?;
    let dos = m.bits(bit(Point::Do(0)), DO).await?;
    // Reading the overflow and latch flags clears them (the module's documented behaviour).
    let flags = if flags { m.bits(bit(Point::CounterRun(0)), 4 * DI).await? } else { vec![false; 4 * usize::from(DI)] };
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
