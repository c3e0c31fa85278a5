//! The module's named resources (`/api/v1/{resource}`, `/{n}` for a list's item, `/{field}`
//! to write one, as `remodaq_protocol::resources` describes them): their fields' values as
//! JSON, and a field's write as a Modbus request ([`write_request`]).

use core::fmt::Write as _;

use embassy_sync::blocking_mutex::raw::RawMutex;
use embedded_storage_async::nor_flash::NorFlash;
use picoserve::response::StatusCode;
use remodaq_protocol::m8318::{InputType, REG_INPUT_TYPE};
use remodaq_protocol::m8350::{DiMode, REG_DI_MODE};
use remodaq_protocol::resources::{self, Field, Format, Resource};
use remodaq_protocol::{u32_low_first, Table};
use remodaq_shared::modbus::{Pdu, RegisterMap};
use remodaq_shared::module::SettingsAccess;

use super::api::{Answer, Api, Json};
use super::registers::readable;
use remodaq_shared::json::Object;

/// The most values one resource read copies under the map's lock (the 8350's 12 DIs of 7
/// shown fields).
const MAX_VALUES: usize = 96;

/// What a field reads as.
#[derive(Clone, Copy)]
enum Seen {
    /// The module does not map it (left out of the answer).
    Unmapped,
    /// `null` (a DI's frequency outside frequency mode).
    Null,
    /// Its value (two registers: low word first).
    Value(u32),
}

impl<R: RawMutex, M: RegisterMap + SettingsAccess, F: NorFlash> Api<'_, R, M, F> {
    /// `GET /api/v1/{resource}` (every item) or `/api/v1/{resource}/{n}` (one).
    pub(super) async fn show(&self, out: &mut Json, r: &Resource, item: Option<u16>) -> Answer {
        let items = match item {
            Some(n) => n..n + 1,
            None => 0..r.count.max(1),
        };
        let shown = || r.fields.iter().filter(|f| f.shown);
        let mut values: heapless::Vec<Seen, MAX_VALUES> = heapless::Vec::new();
        let input_type = {
            let mut map = self.map.lock().await;
            for n in items.clone() {
                for f in shown() {
                    let _ = values.push(seen(&mut *map, f, n));
                }
            }
            let engineering = r.fields.iter().any(|f| f.format == Format::Engineering);
            engineering.then(|| InputType::from_code(map.observe(Table::Registers, REG_INPUT_TYPE) as u8)).flatten()
        };
        let a = Answer::new(out, StatusCode::OK);
        let list = item.is_none() && r.count > 0;
        if list {
            let _ = write!(out, "{{\"{}\":[", r.name);
        }
        let mut values = values.iter();
        for n in items {
            // The executor is shared with Modbus: formatting a long list gives way between
            // items, so that a Modbus answer waits for one item at most (docs/web.md).
            embassy_futures::yield_now().await;
            if n > 0 && list {
                out.push(',');
            }
            out.push('{');
            let mut first = true;
            for (f, v) in shown().zip(&mut values) {
                let Seen::Value(v) = *v else {
                    if matches!(v, Seen::Null) {
                        let _ = write!(out, "{}\"{}\":null", if first { "" } else { "," }, f.name);
                        first = false;
                    }
                    continue;
                };
                let _ = write!(out, "{}\"{}\":", if first { "" } else { "," }, f.name);
                first = false;
                json_value(out, f, v, input_type.as_ref());
            }
            out.push('}');
        }
        if list {
            out.push_str("]}");
        }
        a
    }

    /// `PUT /api/v1/{resource}[/{n}]/{field}` with `{"value": ...}`: one Modbus write.
    pub(super) async fn change(&self, out: &mut Json, f: &Field, n: u16, body: &[u8]) -> Answer {
        match write_request(f, n, body) {
            Ok(request) => self.apply(out, &request, f.name).await,
            Err(WriteError::ReadOnly) => {
                Answer::error(out, StatusCode::METHOD_NOT_ALLOWED, "the field is read-only", Some(f.name))
            }
            Err(WriteError::NotAValue) => {
                Answer::error(out, StatusCode::UNPROCESSABLE_ENTITY, "not a value of this field", Some(f.name))
            }
        }
    }
}

/// Why a body is no write of a field.
#[derive(Debug, PartialEq, Eq)]
pub enum WriteError {
    /// The API does not write this field.
    ReadOnly,
    /// The body is not `{"value": ...}` with a value of the field's format.
    NotAValue,
}

/// The Modbus write request of a body `{"value": ...}` for field `f` of item `n`: code 05 for
/// a bit, 06 for a register, 16 for a 32-bit value; the register map still checks the value.
pub fn write_request(f: &Field, n: u16, body: &[u8]) -> Result<Pdu, WriteError> {
    if !f.writable {
        return Err(WriteError::ReadOnly);
    }
    let addr = f.addr(n);
    let value = Object::parse(body);
    let request = match f.format {
        Format::Bool => value.and_then(|o| o.bool("value")).map(|v| Pdu::bit(addr, v)),
        Format::Word | Format::InputType => value.and_then(|o| o.u16("value")).map(|v| Pdu::word(addr, v)),
        Format::Long => value.and_then(|o| o.u32("value")).map(|v| Pdu::long(addr, v)),
        // A decimal number of °C with at most two decimals (no float parsing in the image);
        // the map checks the range.
        Format::Hundredths => value
            .and_then(|o| o.number("value"))
            .and_then(hundredths)
            .and_then(|h| i16::try_from(h).ok())
            .map(|h| Pdu::word(addr, h as u16)),
        Format::Named(names) => value
            .and_then(|o| o.str("value"))
            .and_then(|v| names.iter().position(|name| *name == v))
            .map(|i| Pdu::word(addr, i as u16)),
        Format::MaskBit | Format::Engineering | Format::Frequency | Format::Ipv4 => return Err(WriteError::ReadOnly),
    };
    request.ok_or(WriteError::NotAValue)
}

/// A JSON number (`number`, as [`Object::number`] gives it) of at most two decimals (`-2`,
/// `1.25`), in hundredths.
fn hundredths(number: &str) -> Option<i32> {
    let (negative, digits) = match number.strip_prefix('-') {
        Some(digits) => (true, digits),
        None => (false, number),
    };
    let (whole, fraction) = match digits.split_once('.') {
        Some((whole, fraction)) if !fraction.is_empty() => (whole, fraction),
        Some(_) => return None,
        None => (digits, ""),
    };
    let decimal = |t: &str| !t.is_empty() && t.len() <= 5 && t.bytes().all(|b| b.is_ascii_digit());
    if !decimal(whole) || !(fraction.is_empty() || decimal(fraction)) || fraction.len() > 2 {
        return None;
    }
    let cents = match fraction.len() {
        0 => 0,
        1 => fraction.parse::<i32>().ok()? * 10,
        _ => fraction.parse::<i32>().ok()?,
    };
    let h = whole.parse::<i32>().ok()? * 100 + cents;
    Some(if negative { -h } else { h })
}

/// Writes `thousandths` as a decimal number with three decimals.
fn write_thousandths(json: &mut Json, thousandths: i64) -> core::fmt::Result {
    let sign = if thousandths < 0 { "-" } else { "" };
    let a = thousandths.unsigned_abs();
    write!(json, "{sign}{}.{:03}", a / 1000, a % 1000)
}

/// What field `f` of item `n` reads as, from the map as it stands.
fn seen<M: RegisterMap>(map: &mut M, f: &Field, n: u16) -> Seen {
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
fn json_value(json: &mut Json, f: &Field, v: u32, input_type: Option<&InputType>) {
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
            Some(t) => {
                let (lo, hi) = (t.lo as i64, t.hi as i64);
                write_thousandths(json, lo * 1000 + (i64::from(v as u16) * (hi - lo) * 1000 + 32767) / 65535)
            }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimal_numbers_in_hundredths() {
        for (body, want) in [
            (r#"{"value":1.25}"#, Some(125)),
            (r#"{"value":-2}"#, Some(-200)),
            (r#"{"value":-0.5}"#, Some(-50)),
            (r#" { "value" : 60 } "#, Some(6000)),
            (r#"{"value":1.2}"#, Some(120)),
            (r#"{"value":1.250}"#, None),
            (r#"{"value":1.}"#, None),
            (r#"{"value":.5}"#, None),
            (r#"{"value":1e2}"#, None),
            (r#"{"value":"1"}"#, None),
            (r#"{"value":--1}"#, None),
            (r#"{"value":123456}"#, None),
            (r#"{"other":1}"#, None),
        ] {
            let got = Object::parse(body.as_bytes()).and_then(|o| o.number("value")).and_then(hundredths);
            assert_eq!(got, want, "{body}");
        }
    }

    #[test]
    fn thousandths_as_decimals() {
        for (t, want) in [(1200, "1.200"), (-250_000, "-250.000"), (-5, "-0.005"), (0, "0.000")] {
            let mut json = Json::default();
            write_thousandths(&mut json, t).unwrap();
            assert_eq!(json.text.as_str(), want);
        }
    }
}
