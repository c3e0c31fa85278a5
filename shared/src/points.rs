//! A module's named points (`remodaq_protocol::resources`) as they stand: what a field reads as
//! in the register map ([`seen`]) and its JSON value ([`json_value`]), for every service that
//! shows them: the web console's API and MQTT (one formatter: the same numbers everywhere, and
//! as a Modbus read of the same registers gives them).

use core::fmt::Write;

use remodaq_protocol::m8318::InputType;
use remodaq_protocol::m8350::{DiMode, REG_DI_MODE};
use remodaq_protocol::resources::{self, Field, Format};
use remodaq_protocol::{u32_low_first, Table};

use crate::modbus::RegisterMap;

/// What a field reads as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Seen {
    /// The module does not map it (left out of the answer).
    Unmapped,
    /// `null` (a DI's frequency outside frequency mode).
    Null,
    /// Its value (two registers: low word first).
    Value(u32),
}

/// Whether `n` addresses from `addr` lie inside the 16-bit space and the map lets them be read.
pub fn readable<M: RegisterMap>(map: &M, table: Table, addr: u16, n: u16) -> bool {
    u32::from(addr) + u32::from(n) <= 0x1_0000 && map.allows(table, addr, n, false)
}

/// What field `f` of item `n` reads as, from the map as it stands.
pub fn seen<M: RegisterMap>(map: &mut M, f: &Field, n: u16) -> Seen {
    let addr = f.addr(n);
    if !readable(map, f.table, addr, f.words()) {
        return Seen::Unmapped;
    }
    if matches!(f.format, Format::Long | Format::Ipv4) && f.table == Table::Registers {
        let mut words = [0u16; 2];
        map.observe_registers(addr, &mut words);
        return Seen::Value(u32_low_first(words[0], words[1]));
    }
    let low = map.observe(f.table, addr);
    Seen::Value(match f.format {
        Format::MaskBit => u32::from(low >> (n % 16) & 1),
        Format::Frequency => {
            if map.observe(Table::Registers, REG_DI_MODE + n) != DiMode::Frequency as u16 {
                return Seen::Null;
            }
            u32::from(low)
        }
        _ => u32::from(low),
    })
}

/// Writes the JSON value of field `f` read as `v` (`input_type`: the 8318's, for its values).
pub fn json_value(json: &mut impl Write, f: &Field, v: u32, input_type: Option<&InputType>) {
    let _ = match f.format {
        Format::Bool | Format::MaskBit => write!(json, "{}", v != 0),
        Format::Word | Format::Long | Format::Frequency => write!(json, "{v}"),
        Format::Hundredths => {
            let h = i32::from(v as u16 as i16);
            let sign = if h < 0 { "-" } else { "" };
            write!(json, "{sign}{}.{:02}", h.unsigned_abs() / 100, h.unsigned_abs() % 100)
        }
        Format::Named(names) => match names.get(v as usize) {
            Some(name) => write!(json, "\"{name}\""),
            None => write!(json, "{v}"),
        },
        // spec §2.3 inverted in integers (every range's ends are whole units): lo + raw / 65535
        // x (hi - lo), in thousandths, rounded (no float formatting in the image).
        Format::Engineering => match input_type {
            Some(t) => write_thousandths(json, engineering_thousandths(t, v as u16)),
            None => write!(json, "null"),
        },
        Format::InputType => match InputType::from_code(v as u8).filter(|_| v <= 0xFF) {
            Some(t) => {
                let thermocouple = t.thermocouple().map_or("", |tc| tc.letter());
                write!(
                    json,
                    "{{\"code\":{v},\"unit\":\"{}\",\"lo\":{},\"hi\":{},\"thermocouple\":\"{thermocouple}\"}}",
                    resources::unit(&t),
                    t.lo as i64,
                    t.hi as i64
                )
            }
            None => write!(json, "{{\"code\":{v}}}"),
        },
        Format::Ipv4 => {
            let [c, d, a, b] = v.to_be_bytes();
            write!(json, "\"{a}.{b}.{c}.{d}\"")
        }
    };
}

/// The engineering value of raw code `raw` for input type `t`, in thousandths of its unit: spec
/// §2.3 inverted in integers (every range's ends are whole units): lo + raw / 65535 x (hi - lo),
/// rounded (no float formatting in the image).
pub fn engineering_thousandths(t: &InputType, raw: u16) -> i64 {
    let (lo, hi) = (t.lo as i64, t.hi as i64);
    lo * 1000 + (i64::from(raw) * (hi - lo) * 1000 + 32767) / 65535
}

/// Writes `thousandths` as a decimal number with three decimals.
fn write_thousandths(json: &mut impl Write, thousandths: i64) -> core::fmt::Result {
    let sign = if thousandths < 0 { "-" } else { "" };
    let a = thousandths.unsigned_abs();
    write!(json, "{sign}{}.{:03}", a / 1000, a % 1000)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thousandths_as_decimals() {
        for (t, want) in [(1200, "1.200"), (-250_000, "-250.000"), (-5, "-0.005"), (0, "0.000")] {
            let mut json = heapless::String::<16>::new();
            write_thousandths(&mut json, t).unwrap();
            assert_eq!(json.as_str(), want);
        }
    }
}
