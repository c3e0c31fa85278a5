//! The 8350's output commands (issue #40, docs/mqtt.md), published to `<prefix>/do/<n>/set`:
//! a level, `{"level": true}`, or a pulse train, `{"low_ms": 0.5, "high_ms": 0.5, "count": 100}`
//! (widths in ms to 0.1 ms, the spec's unit; a count of 0 runs until stopped). A command is
//! carried out as the Modbus writes a master would make for it ([`Command::requests`]), through
//! the same register map and its checks; what the map refuses changes nothing.

use remodaq_protocol::m8350::{BIT_DO, REG_DO_MODE, REG_PULSE};
use remodaq_shared::json::Object;
use remodaq_shared::modbus::Pdu;

/// The longest command payload, bytes: a pulse command with every field at its longest is
/// about 70.
pub const MAX_COMMAND: usize = 128;

/// A DO mode register's values (spec §3.2).
const MODE_NORMAL: u16 = 0;
const MODE_PULSE: u16 = 1;

/// What a command asks of one output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    /// Normal mode, driven at this level.
    Level(bool),
    /// Pulse mode, a train started.
    Pulse {
        /// The low width, 0.1 ms.
        low: u32,
        /// The high width, 0.1 ms.
        high: u32,
        /// Pulses, 0: until stopped.
        count: u32,
    },
}

/// Why a command payload was refused (each counted in the diagnostics).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// Longer than [`MAX_COMMAND`].
    TooLong,
    /// Not one of the two forms.
    Malformed,
}

impl Command {
    /// The command in `payload`.
    pub fn parse(payload: &[u8]) -> Result<Self, Refusal> {
        if payload.len() > MAX_COMMAND {
            return Err(Refusal::TooLong);
        }
        let o = Object::parse(payload).ok_or(Refusal::Malformed)?;
        let pulse = ["low_ms", "high_ms", "count"].map(|name| o.get(name).is_some());
        match (o.get("level"), pulse) {
            (Some(_), [false, false, false]) => o.bool("level").map(Command::Level).ok_or(Refusal::Malformed),
            (None, [true, true, true]) => {
                let low = o.number("low_ms").and_then(tenths).ok_or(Refusal::Malformed)?;
                let high = o.number("high_ms").and_then(tenths).ok_or(Refusal::Malformed)?;
                let count = o.u32("count").ok_or(Refusal::Malformed)?;
                Ok(Command::Pulse { low, high, count })
            }
            _ => Err(Refusal::Malformed),
        }
    }

    /// The Modbus write requests that carry the command out on output `n` (spec §3.1, §3.2,
    /// §3.4), in order: a level sets normal mode then the output; a train sets its widths and
    /// count, pulse mode, then starts it (writing 1 to the output).
    pub fn requests(&self, n: u8) -> heapless::Vec<Pdu, 5> {
        let n = u16::from(n);
        let mut r = heapless::Vec::new();
        let _ = match *self {
            Command::Level(level) => {
                r.push(Pdu::word(REG_DO_MODE + n, MODE_NORMAL)).and_then(|()| r.push(Pdu::bit(BIT_DO + n, level)))
            }
            Command::Pulse { low, high, count } => r
                .push(Pdu::long(REG_PULSE + 2 * n, low))
                .and_then(|()| r.push(Pdu::long(REG_PULSE + 12 + 2 * n, high)))
                .and_then(|()| r.push(Pdu::long(REG_PULSE + 24 + 2 * n, count)))
                .and_then(|()| r.push(Pdu::word(REG_DO_MODE + n, MODE_PULSE)))
                .and_then(|()| r.push(Pdu::bit(BIT_DO + n, true))),
        };
        r
    }
}

/// A JSON number of milliseconds with at most one decimal (`2`, `0.5`) in tenths; `None` for a
/// sign, an exponent, more decimals or more than 9 whole digits.
fn tenths(number: &str) -> Option<u32> {
    let (whole, fraction) = match number.split_once('.') {
        Some((whole, fraction)) if fraction.len() == 1 => (whole, fraction),
        Some(_) => return None,
        None => (number, "0"),
    };
    let digits = |t: &str| !t.is_empty() && t.len() <= 9 && t.bytes().all(|b| b.is_ascii_digit());
    if !digits(whole) || !digits(fraction) {
        return None;
    }
    whole.parse::<u32>().ok()?.checked_mul(10)?.checked_add(fraction.parse().ok()?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_two_forms() {
        assert_eq!(Command::parse(br#"{"level": true}"#), Ok(Command::Level(true)));
        assert_eq!(Command::parse(br#"{"level":false}"#), Ok(Command::Level(false)));
        assert_eq!(
            Command::parse(br#"{"low_ms": 0.5, "high_ms": 2, "count": 100}"#),
            Ok(Command::Pulse { low: 5, high: 20, count: 100 })
        );
        assert_eq!(
            Command::parse(br#"{"count": 0, "high_ms": 429496729.5, "low_ms": 0.1}"#),
            Ok(Command::Pulse { low: 1, high: 4_294_967_295, count: 0 })
        );
    }

    #[test]
    fn anything_else_is_refused() {
        for bad in [
            &br#"{"level": 1}"#[..],
            br#"{"level": true, "count": 1}"#,
            br#"{"low_ms": 0.5, "high_ms": 0.5}"#,
            br#"{"low_ms": 0.05, "high_ms": 0.5, "count": 1}"#,
            br#"{"low_ms": -1, "high_ms": 0.5, "count": 1}"#,
            br#"{"low_ms": 1e3, "high_ms": 0.5, "count": 1}"#,
            br#"{"low_ms": 429496729.6, "high_ms": 0.5, "count": 1}"#,
            br#"{"low_ms": 1, "high_ms": 1, "count": 4294967296}"#,
            br#"{"low_ms": "1", "high_ms": 1, "count": 1}"#,
            br#"{"level": {"nested": true}}"#,
            b"true",
            b"",
            b"\xff",
        ] {
            assert_eq!(Command::parse(bad), Err(Refusal::Malformed), "{}", String::from_utf8_lossy(bad));
        }
        let long = std::format!("{{\"level\": true{}}}", " ".repeat(MAX_COMMAND));
        assert_eq!(Command::parse(long.as_bytes()), Err(Refusal::TooLong));
    }

    use std::string::String;

    /// The writes, with the spec's addresses (modules.md §3.1: DO n coil 10h + n; §3.2: low
    /// width 18h + 2n, high width 24h + 2n, count 30h + 2n, 32-bit low word first; DO n mode
    /// 110h + n, 0 normal, 1 pulse).
    #[test]
    fn the_writes_a_master_would_make() {
        let bytes = |r: &heapless::Vec<Pdu, 5>| r.iter().map(|p| p.bytes().to_vec()).collect::<std::vec::Vec<_>>();
        assert_eq!(
            bytes(&Command::Level(true).requests(2)),
            [std::vec![0x06, 0x01, 0x12, 0x00, 0x00], std::vec![0x05, 0x00, 0x12, 0xFF, 0x00]]
        );
        assert_eq!(
            bytes(&Command::Pulse { low: 5, high: 0x0001_0002, count: 100 }.requests(1)),
            [
                std::vec![0x10, 0x00, 0x1A, 0x00, 0x02, 0x04, 0x00, 0x05, 0x00, 0x00],
                std::vec![0x10, 0x00, 0x26, 0x00, 0x02, 0x04, 0x00, 0x02, 0x00, 0x01],
                std::vec![0x10, 0x00, 0x32, 0x00, 0x02, 0x04, 0x00, 0x64, 0x00, 0x00],
                std::vec![0x06, 0x01, 0x11, 0x00, 0x01],
                std::vec![0x05, 0x00, 0x11, 0xFF, 0x00],
            ]
        );
    }
}
