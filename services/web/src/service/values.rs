//! The module's named resources (`/api/v1/{resource}`, `/{n}` for a list's item, `/{field}`
//! to write one, as `remodaq_protocol::resources` describes them): their fields' values as
//! JSON, and a field's write as a Modbus request ([`write_request`]).

use core::fmt::Write as _;

use embassy_sync::blocking_mutex::raw::RawMutex;
use embedded_storage_async::nor_flash::NorFlash;
use picoserve::response::StatusCode;
use remodaq_protocol::m8318::{InputType, REG_INPUT_TYPE};
use remodaq_protocol::resources::{Field, Format, Resource};
use remodaq_protocol::Table;
use remodaq_shared::modbus::{Pdu, RegisterMap};
use remodaq_shared::module::SettingsAccess;
use remodaq_shared::points::{json_value, seen, Seen};

use super::api::{Answer, Api, Json};
use remodaq_shared::json::Object;

/// The most values one resource read copies under the map's lock (the 8350's 12 DIs of 7
/// shown fields).
const MAX_VALUES: usize = 96;

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
}
