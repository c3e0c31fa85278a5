//! The Modbus PDU engine: function codes 01 02 03 04 05 06 15 16 with the quantity limits and
//! exceptions of spec §1.2, on top of any [`RegisterMap`]. Checks run in the order of the Modbus
//! application protocol: function code (01), quantity / byte count / value (03), addresses (02),
//! module-specific values (03), execution (04).

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;

use super::exception::Exception;
use super::map::{RegisterMap, Table, WriteValues};

/// Largest PDU (Modbus/TCP length field 254 = unit id + 253 bytes).
pub const MAX_PDU: usize = 253;

const READ_COILS: u8 = 0x01;
const READ_DISCRETE_INPUTS: u8 = 0x02;
const READ_HOLDING_REGISTERS: u8 = 0x03;
const READ_INPUT_REGISTERS: u8 = 0x04;
pub(crate) const WRITE_SINGLE_COIL: u8 = 0x05;
pub(crate) const WRITE_SINGLE_REGISTER: u8 = 0x06;
pub(crate) const WRITE_MULTIPLE_COILS: u8 = 0x0F;
pub(crate) const WRITE_MULTIPLE_REGISTERS: u8 = 0x10;

const MAX_READ_BITS: u16 = 2000;
const MAX_READ_REGISTERS: u16 = 125;
const MAX_WRITE_BITS: u16 = 1968;
const MAX_WRITE_REGISTERS: u16 = 123;

/// Answer one request PDU (function code first) from the client at `from` into `resp`;
/// returns the response PDU length. Never panics: every malformed request gets an exception
/// response. The map is locked once, for the checks, the reads and a write that only touches
/// RAM ([`RegisterMap::write_now`]); a write that persists is carried out by
/// [`RegisterMap::write`] after that lock is released, so reads go on while it commits to
/// flash.
pub async fn handle_pdu<R: RawMutex, M: RegisterMap>(
    map: &Mutex<R, M>,
    from: [u8; 4],
    req: &[u8],
    resp: &mut [u8; MAX_PDU],
) -> usize {
    // Uncontended (the common case), the lock is taken without a pending future.
    let mut locked = match map.try_lock() {
        Ok(locked) => locked,
        Err(_) => map.lock().await,
    };
    match prepare(&mut *locked, from, req, resp) {
        Step::Answered(len) => len,
        Step::Write { start, values } => {
            if let Some(result) = locked.write_now(start, &values) {
                return written(req, resp, result);
            }
            drop(locked);
            written(req, resp, M::write(map, start, &values).await)
        }
    }
}

/// Whether the write request `req` from the client at `from` would be carried out: the map's
/// admission and every check [`handle_pdu`] makes, nothing applied. `Err` holds the exception
/// code it would answer with (01 for a request that is no write). A service that carries out
/// several writes as one (MQTT's output commands) checks them all first.
pub fn check_write<M: RegisterMap>(map: &mut M, from: [u8; 4], req: &[u8]) -> Result<(), u8> {
    let mut resp = [0u8; MAX_PDU];
    match prepare(map, from, req, &mut resp) {
        Step::Write { .. } => Ok(()),
        Step::Answered(_) if resp[0] & 0x80 != 0 => Err(resp[1]),
        Step::Answered(_) => Err(Exception::IllegalFunction as u8),
    }
}

/// The answer to a write once applied: codes 05, 06, 15 and 16 answer with the request's
/// function and first four data bytes; a failed apply with its exception.
#[inline]
fn written(req: &[u8], resp: &mut [u8; MAX_PDU], result: Result<(), Exception>) -> usize {
    match (result, req.get(..5)) {
        (Ok(()), Some(echo)) => {
            resp[..5].copy_from_slice(echo);
            5
        }
        (Ok(()), None) => exception(resp, req.first().copied().unwrap_or(0), Exception::ServerDeviceFailure),
        (Err(e), _) => exception(resp, req.first().copied().unwrap_or(0), e),
    }
}

/// What is left to do after the synchronous part of a request.
enum Step<'a> {
    /// The answer is in the response buffer, this long.
    Answered(usize),
    /// A validated write, to apply (all or nothing).
    Write {
        /// First address.
        start: u16,
        /// The values.
        values: WriteValues<'a>,
    },
}

/// Everything of a request from the client at `from` but applying a write: the map's
/// admission, the checks in the order of the Modbus application protocol, and reads answered
/// in place.
#[inline]
fn prepare<'a, M: RegisterMap>(map: &mut M, from: [u8; 4], req: &'a [u8], resp: &mut [u8; MAX_PDU]) -> Step<'a> {
    let Some((&function, data)) = req.split_first() else {
        // An empty PDU has no function code to answer with: treat it as an unknown function 0.
        return Step::Answered(exception(resp, 0, Exception::IllegalFunction));
    };
    match map.admit(from, function).and_then(|()| execute(map, function, data, resp)) {
        Ok(step) => step,
        Err(e) => Step::Answered(exception(resp, function, e)),
    }
}

fn exception(resp: &mut [u8; MAX_PDU], function: u8, e: Exception) -> usize {
    resp[0] = function | 0x80;
    resp[1] = e as u8;
    2
}

/// Checks that `start..start + quantity` stays inside the 16-bit address space and that every
/// address allows the access.
#[inline]
fn check_range<M: RegisterMap>(map: &M, table: Table, start: u16, quantity: u16, write: bool) -> Result<(), Exception> {
    if u32::from(start) + u32::from(quantity) > 0x1_0000 || !map.allows(table, start, quantity, write) {
        return Err(Exception::IllegalDataAddress);
    }
    Ok(())
}

#[inline]
fn execute<'a, M: RegisterMap>(
    map: &mut M,
    function: u8,
    data: &'a [u8],
    resp: &mut [u8; MAX_PDU],
) -> Result<Step<'a>, Exception> {
    match function {
        READ_COILS | READ_DISCRETE_INPUTS => {
            let (start, quantity) = fixed_request(data)?;
            if !(1..=MAX_READ_BITS).contains(&quantity) {
                return Err(Exception::IllegalDataValue);
            }
            check_range(map, Table::Bits, start, quantity, false)?;
            let bytes = usize::from(quantity).div_ceil(8);
            resp[0] = function;
            resp[1] = bytes as u8;
            let out = &mut resp[2..2 + bytes];
            out.fill(0);
            map.read_bits(start, quantity, out);
            Ok(Step::Answered(2 + bytes))
        }
        READ_HOLDING_REGISTERS | READ_INPUT_REGISTERS => {
            let (start, quantity) = fixed_request(data)?;
            if !(1..=MAX_READ_REGISTERS).contains(&quantity) {
                return Err(Exception::IllegalDataValue);
            }
            check_range(map, Table::Registers, start, quantity, false)?;
            let bytes = 2 * usize::from(quantity);
            resp[0] = function;
            resp[1] = bytes as u8;
            map.read_registers(start, &mut resp[2..2 + bytes]);
            Ok(Step::Answered(2 + bytes))
        }
        WRITE_SINGLE_COIL => {
            let &[a0, a1, v0, v1] = data else { return Err(Exception::IllegalDataValue) };
            let values = match [v0, v1] {
                [0xFF, 0x00] => WriteValues::bits(&BIT_ON, 1),
                [0x00, 0x00] => WriteValues::bits(&BIT_OFF, 1),
                _ => return Err(Exception::IllegalDataValue),
            };
            let addr = u16::from_be_bytes([a0, a1]);
            if !map.allows(Table::Bits, addr, 1, true) {
                return Err(Exception::IllegalDataAddress);
            }
            map.validate(addr, &values)?;
            Ok(Step::Write { start: addr, values })
        }
        WRITE_SINGLE_REGISTER => {
            // One address is always inside the 16-bit space: only the map's rule to check.
            let (&[a0, a1], value) = data.split_first_chunk::<2>().ok_or(Exception::IllegalDataValue)?;
            if value.len() != 2 {
                return Err(Exception::IllegalDataValue);
            }
            let addr = u16::from_be_bytes([a0, a1]);
            if !map.allows(Table::Registers, addr, 1, true) {
                return Err(Exception::IllegalDataAddress);
            }
            let values = WriteValues::registers(value);
            map.validate(addr, &values)?;
            Ok(Step::Write { start: addr, values })
        }
        // One arm per code, so each compiles with its table and limits as constants.
        WRITE_MULTIPLE_COILS => multiple_write(map, data, Table::Bits, MAX_WRITE_BITS),
        WRITE_MULTIPLE_REGISTERS => multiple_write(map, data, Table::Registers, MAX_WRITE_REGISTERS),
        _ => Err(Exception::IllegalFunction),
    }
}

/// Codes 15 and 16: start(2) quantity(2) byte count(1) values(byte count).
#[inline(always)]
fn multiple_write<'a, M: RegisterMap>(
    map: &mut M,
    data: &'a [u8],
    table: Table,
    limit: u16,
) -> Result<Step<'a>, Exception> {
    let Some((&[s0, s1, q0, q1, byte_count], values)) = data.split_first_chunk::<5>() else {
        return Err(Exception::IllegalDataValue);
    };
    let (start, quantity, byte_count) =
        (u16::from_be_bytes([s0, s1]), u16::from_be_bytes([q0, q1]), usize::from(byte_count));
    let expected = match table {
        Table::Bits => usize::from(quantity).div_ceil(8),
        Table::Registers => 2 * usize::from(quantity),
    };
    if !(1..=limit).contains(&quantity) || byte_count != expected || values.len() != byte_count {
        return Err(Exception::IllegalDataValue);
    }
    check_range(map, table, start, quantity, true)?;
    let values = match table {
        Table::Bits => WriteValues::bits(values, quantity),
        Table::Registers => WriteValues::registers(values),
    };
    map.validate(start, &values)?;
    Ok(Step::Write { start, values })
}

const BIT_ON: [u8; 1] = [1];
const BIT_OFF: [u8; 1] = [0];

/// The four-byte body shared by codes 01-06: two big-endian words, nothing more.
#[inline]
fn fixed_request(data: &[u8]) -> Result<(u16, u16), Exception> {
    match data {
        &[a, b, c, d] => Ok((u16::from_be_bytes([a, b]), u16::from_be_bytes([c, d]))),
        _ => Err(Exception::IllegalDataValue),
    }
}
