//! The writes that configure and drive a module, each to its documented registers (spec §2-3,
//! extensions §2-3): one implementation for the CLI's `config` and the utility's panels.

use remodaq_protocol::m8318::{self, REG_CJC_OFFSET, REG_ENABLE_MASK, REG_INPUT_TYPE, REG_OPEN_VALUE};
use remodaq_protocol::m8350::{self, wd_mode, DiMode, Point, PulseField, Word};
use remodaq_protocol::words_low_first;

use crate::modbus::Module;
use crate::reading::{bit, reg, DI_MODES};
use crate::Error;

/// What to do with an input's counter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CounterAction {
    Start,
    Stop,
    Clear,
}

/// One setting or command, as the module takes it.
#[derive(Clone, Debug, PartialEq)]
pub enum Write {
    /// 8318: the input type code of all channels (40201).
    InputType(u16),
    /// 8318: enabled channels (40221), bit n = channel n.
    Enable(u16),
    /// 8318: cold-junction offset (40216), 0.01 °C steps, -5000 to 5000.
    CjcOffset(i32),
    /// 8318: an open input reads 0000h (downscale) rather than FFFFh (40233).
    OpenDownscale(bool),
    /// 8350: host watchdog timeout in 0.1 s (0: off) and its mode (40305, 40307).
    Watchdog { tenths: u32, writes_only: bool, auto_clear: bool },
    /// 8350: end the watchdog's safe state (0 to 40308).
    WatchdogClear,
    /// 8350: safe-state levels (40306), bit n = DO n.
    SafeLevels(u16),
    /// 8350: power-on levels (40309), bit n = DO n.
    PowerOnLevels(u16),
    /// 8350: mode of input n (40257 + n).
    DiMode(u16, DiMode),
    /// 8350: one mode for every input (40257-40268 in one request).
    DiModeAll(DiMode),
    /// 8350: output n in pulse mode (true) or level mode (40273 + n).
    DoPulseMode(u16, bool),
    /// 8350: output n's pulse train: low and high widths in 0.1 ms, pulses per train (0: for
    /// ever).
    Pulse { channel: u16, low: u32, high: u32, count: u32 },
    /// 8350: pulses added to output n's running train (40061 + 2n).
    Extra(u16, u32),
    /// 8350: input n's counter.
    Counter(u16, CounterAction),
    /// 8350: clear input n's latch flag.
    LatchClear(u16),
    /// 8350: output n on or off (in pulse mode: start or stop the train).
    Do(u16, bool),
    /// Either module: one holding register by its PDU address.
    Register(u16, u16),
}

fn channel(n: u16, count: usize) -> Result<u8, Error> {
    u8::try_from(n)
        .ok()
        .filter(|&n| usize::from(n) < count)
        .ok_or_else(|| Error::Other(format!("channel {n} does not exist (0..{})", count - 1)))
}

impl Write {
    /// The model this is for (`None`: either).
    fn model(&self) -> Option<u16> {
        match self {
            Write::InputType(_) | Write::Enable(_) | Write::CjcOffset(_) | Write::OpenDownscale(_) => {
                Some(m8318::MODULE_NAME)
            }
            Write::Register(..) => None,
            _ => Some(m8350::MODULE_NAME),
        }
    }
}

/// Writes `w` to the module; says what it did.
pub async fn apply(m: &mut Module, w: &Write) -> Result<String, Error> {
    if let Some(model) = w.model() {
        m.expect(model)?;
    }
    Ok(match *w {
        Write::InputType(code) => {
            if m8318::InputType::from_code(code as u8).is_none() || code > 0xFF {
                return Err(Error::Other(format!("{code:02X} is not an input type code")));
            }
            m.write_regs(REG_INPUT_TYPE, &[code]).await?;
            format!("input type {code:02X}")
        }
        Write::Enable(mask) => {
            if mask > 0xFF {
                return Err(Error::Other("the enable mask has 8 bits (0x00 to 0xFF)".into()));
            }
            m.write_regs(REG_ENABLE_MASK, &[mask]).await?;
            format!("enabled channels {mask:#04x}")
        }
        Write::CjcOffset(hundredths) => {
            let limit = i32::from(m8318::CJC_OFFSET_LIMIT);
            if !(-limit..=limit).contains(&hundredths) {
                return Err(Error::Other("the CJC offset is -50.00 to 50.00 °C".into()));
            }
            m.write_regs(REG_CJC_OFFSET, &[m8318::cjc_offset_to_register(hundredths as i16)]).await?;
            format!("CJC offset {:+.2} °C", f64::from(hundredths) / 100.0)
        }
        Write::OpenDownscale(downscale) => {
            m.write_regs(REG_OPEN_VALUE, &[u16::from(downscale)]).await?;
            format!("open inputs read {}", if downscale { "0000h (downscale)" } else { "FFFFh (upscale)" })
        }
        Write::WatchdogClear => {
            m.write_regs(m8350::REG_WD_STATUS, &[0]).await?;
            "host watchdog cleared: outputs keep their safe levels until written".to_string()
        }
        Write::Watchdog { tenths, writes_only, auto_clear } => {
            if tenths > u32::from(m8350::WD_TIMEOUT_MAX) {
                return Err(Error::Other("the watchdog timeout is 0.1 to 600 s, or off".into()));
            }
            let mode =
                if writes_only { wd_mode::WRITES_ONLY } else { 0 } | if auto_clear { wd_mode::AUTO_CLEAR } else { 0 };
            m.write_regs(m8350::REG_WD_MODE, &[mode]).await?;
            m.write_regs(m8350::REG_WD_TIMEOUT, &[tenths as u16]).await?;
            if tenths == 0 {
                "host watchdog off".to_string()
            } else {
                format!(
                    "host watchdog {} s, fed by {}, cleared {}",
                    f64::from(tenths) / 10.0,
                    if writes_only { "writes" } else { "any request" },
                    if auto_clear { "automatically" } else { "by `watchdog clear`" }
                )
            }
        }
        Write::SafeLevels(v) | Write::PowerOnLevels(v) => {
            if v > 0x3F {
                return Err(Error::Other("output levels have 6 bits (DO5..DO0)".into()));
            }
            let (register, what) = match w {
                Write::SafeLevels(_) => (m8350::REG_SAFE_VALUES, "safe"),
                _ => (m8350::REG_POWER_ON, "power-on"),
            };
            m.write_regs(register, &[v]).await?;
            format!("{what} levels {v:06b} (DO5..DO0)")
        }
        Write::DiMode(n, mode) => {
            let n = channel(n, m8350::DI_CHANNELS)?;
            m.write_regs(reg(Point::DiMode(n)), &[mode as u16]).await?;
            format!("DI{n} mode {}", DI_MODES[mode as usize])
        }
        Write::DiModeAll(mode) => {
            m.write_regs(reg(Point::DiMode(0)), &[mode as u16; m8350::DI_CHANNELS]).await?;
            format!("every DI in mode {}", DI_MODES[mode as usize])
        }
        Write::DoPulseMode(n, pulse) => {
            let n = channel(n, m8350::DO_CHANNELS)?;
            m.write_regs(reg(Point::DoMode(n)), &[u16::from(pulse)]).await?;
            format!("DO{n} mode {}", if pulse { "pulse" } else { "normal" })
        }
        Write::Pulse { channel: n, low, high, count } => {
            let n = channel(n, m8350::DO_CHANNELS)?;
            if low == 0 || high == 0 {
                return Err(Error::Other("pulse widths are at least 0.1 ms".into()));
            }
            for (field, value) in [(PulseField::Low, low), (PulseField::High, high), (PulseField::Count, count)] {
                m.write_regs(reg(Point::Pulse(field, n, Word::Low)), &words_low_first(value)).await?;
            }
            format!("DO{n} pulses: low {} ms, high {} ms, count {count}", f64::from(low) / 10.0, f64::from(high) / 10.0)
        }
        Write::Extra(n, pulses) => {
            let n = channel(n, m8350::DO_CHANNELS)?;
            m.write_regs(reg(Point::Pulse(PulseField::Extra, n, Word::Low)), &words_low_first(pulses)).await?;
            format!("DO{n}: {pulses} extra pulses")
        }
        Write::Counter(n, action) => {
            let n = channel(n, m8350::DI_CHANNELS)?;
            match action {
                CounterAction::Start => m.write_bit(bit(Point::CounterRun(n)), true).await?,
                CounterAction::Stop => m.write_bit(bit(Point::CounterRun(n)), false).await?,
                CounterAction::Clear => m.write_bit(bit(Point::CounterClear(n)), true).await?,
            }
            format!("DI{n} counter {}", ["started", "stopped", "cleared"][action as usize])
        }
        Write::LatchClear(n) => {
            let n = channel(n, m8350::DI_CHANNELS)?;
            m.write_bit(bit(Point::Latch(n)), false).await?;
            format!("DI{n} latch cleared")
        }
        Write::Do(n, on) => {
            let n = channel(n, m8350::DO_CHANNELS)?;
            m.write_bit(bit(Point::Do(n)), on).await?;
            format!("DO{n} {}", if on { "on" } else { "off" })
        }
        Write::Register(pdu, v) => {
            m.write_regs(pdu, &[v]).await?;
            format!("register {} ({pdu:#06x}) = {v:#06x}", u32::from(pdu) + 40001)
        }
    })
}
