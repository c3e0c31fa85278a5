//! The registers and coils as Modbus numbers them (`/api/v1/registers/{addr}`,
//! `/api/v1/coils/{addr}`): runs read as they stand, and every write of the API, as a Modbus
//! write request ([`Pdu`]) through the PDU engine.

use core::fmt::Write as _;

use embassy_sync::blocking_mutex::raw::RawMutex;
use embedded_storage_async::nor_flash::NorFlash;
use picoserve::response::StatusCode;
use remodaq_protocol::Table;
use remodaq_shared::modbus::pdu::{handle_pdu, MAX_PDU};
use remodaq_shared::modbus::{Pdu, RegisterMap};
use remodaq_shared::module::SettingsAccess;
use remodaq_shared::points::readable;

use super::api::{Answer, Api, Json};
use remodaq_shared::json::Object;

/// The most registers or coils one GET reads: Modbus's limit for registers (125 of at most
/// "65535," fit [`MAX_ANSWER`](super::api::MAX_ANSWER)); 150 coils (150 "false," fit it,
/// Modbus's 2000 would not).
pub(super) const MAX_READ_REGISTERS: u16 = 125;
pub(super) const MAX_READ_COILS: u16 = 150;

/// The status and text of a Modbus exception as an API error.
fn exception_answer(out: &mut Json, code: u8, field: &str) -> Answer {
    match code {
        2 => Answer::error(out, StatusCode::NOT_FOUND, "address not mapped for this access", Some("address")),
        3 => Answer::error(out, StatusCode::UNPROCESSABLE_ENTITY, "value refused", Some(field)),
        4 => Answer::error(out, StatusCode::INTERNAL_SERVER_ERROR, "the module could not apply it", None),
        // 01 (not a known function) and the access rules' refusal of a write.
        _ => Answer::error(out, StatusCode::FORBIDDEN, "refused by the module", None),
    }
}

impl<R: RawMutex, M: RegisterMap + SettingsAccess, F: NorFlash> Api<'_, R, M, F> {
    /// A run of registers or coils as they stand (no flag cleared: [`RegisterMap::observe`]),
    /// read under one lock of the map. Reads are never refused by the allow-list and, unlike a
    /// Modbus read, do not feed the host watchdog (docs/web.md).
    pub(super) async fn read(&self, out: &mut Json, registers: bool, addr: u16, n: u16) -> Answer {
        let table = if registers { Table::Registers } else { Table::Bits };
        let mut map = self.map.lock().await;
        // Made once the lock is taken: not kept in the connection's future across that wait.
        let mut values = [0u16; MAX_READ_COILS as usize];
        let values = &mut values[..usize::from(n)];
        if !readable(&*map, table, addr, n) {
            return exception_answer(out, 2, "address");
        }
        // addr + i stays within 16 bits: checked above.
        for (i, v) in (0..n).zip(values.iter_mut()) {
            *v = map.observe(table, addr + i);
        }
        // The text is written with the map free for Modbus.
        drop(map);
        let a = Answer::new(out, StatusCode::OK);
        out.push_str("{\"values\":[");
        for (i, v) in values.iter().enumerate() {
            let sep = if i == 0 { "" } else { "," };
            let _ = if registers { write!(out, "{sep}{v}") } else { write!(out, "{sep}{}", *v != 0) };
        }
        out.push_str("]}");
        a
    }

    /// A write of registers or coils at `addr` from a body `{"value": ...}`.
    pub(super) async fn write(&self, out: &mut Json, registers: bool, addr: u16, body: &[u8]) -> Answer {
        let request = if registers {
            match Object::parse(body).and_then(|o| o.u16("value")) {
                Some(v) => Pdu::word(addr, v),
                None => {
                    return Answer::error(out, StatusCode::BAD_REQUEST, "expected {value: 0..65535}", Some("value"))
                }
            }
        } else {
            match Object::parse(body).and_then(|o| o.bool("value")) {
                Some(v) => Pdu::bit(addr, v),
                None => {
                    return Answer::error(out, StatusCode::BAD_REQUEST, "expected {value: true|false}", Some("value"))
                }
            }
        };
        self.apply(out, &request, "value").await
    }

    /// Carries out a write request through the Modbus PDU engine, with this client's address:
    /// the map's admission (the allow-list), checks and commit, as a Modbus write.
    pub(super) async fn apply(&self, out: &mut Json, request: &Pdu, field: &str) -> Answer {
        let mut resp = [0u8; MAX_PDU];
        let len = handle_pdu(self.map, self.peer, request.bytes(), &mut resp).await;
        if len >= 5 && resp[0] == request.bytes()[0] {
            Answer::no_content(out)
        } else {
            exception_answer(out, resp[1], field)
        }
    }
}
