//! The Modbus PDU engine: function codes 01 02 03 04 05 06 15 16 with the quantity limits and
//! exceptions of spec §1.2, on top of any [`RegisterMap`]. Checks run in the order of the Modbus
//! application protocol: function code (01), quantity / byte count / value (03), addresses (02),
//! module-specific values (03), execution (04).

use super::{Exception, RegisterMap, Table, WriteValues};

/// Largest PDU (Modbus/TCP length field 254 = unit id + 253 bytes).
pub const MAX_PDU: usize = 253;

const READ_COILS: u8 = 0x01;
const READ_DISCRETE_INPUTS: u8 = 0x02;
const READ_HOLDING_REGISTERS: u8 = 0x03;
const READ_INPUT_REGISTERS: u8 = 0x04;
const WRITE_SINGLE_COIL: u8 = 0x05;
const WRITE_SINGLE_REGISTER: u8 = 0x06;
const WRITE_MULTIPLE_COILS: u8 = 0x0F;
const WRITE_MULTIPLE_REGISTERS: u8 = 0x10;

const MAX_READ_BITS: u16 = 2000;
const MAX_READ_REGISTERS: u16 = 125;
const MAX_WRITE_BITS: u16 = 1968;
const MAX_WRITE_REGISTERS: u16 = 123;

/// Answer one request PDU (function code first) into `resp`; returns the response PDU length.
/// Never panics: every malformed request gets an exception response.
pub async fn handle_pdu<M: RegisterMap>(map: &mut M, req: &[u8], resp: &mut [u8; MAX_PDU]) -> usize {
    let Some(&function) = req.first() else {
        // An empty PDU has no function code to answer with: treat it as an unknown function 0.
        return exception(resp, 0, Exception::IllegalFunction);
    };
    match execute(map, function, &req[1..], resp).await {
        Ok(len) => len,
        Err(e) => exception(resp, function, e),
    }
}

fn exception(resp: &mut [u8; MAX_PDU], function: u8, e: Exception) -> usize {
    resp[0] = function | 0x80;
    resp[1] = e as u8;
    2
}

fn be16(data: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([data[at], data[at + 1]])
}

/// Checks that `start..start + quantity` stays inside the 16-bit address space and that every
/// address allows the access.
fn check_range<M: RegisterMap>(map: &M, table: Table, start: u16, quantity: u16, write: bool) -> Result<(), Exception> {
    if u32::from(start) + u32::from(quantity) > 0x1_0000 {
        return Err(Exception::IllegalDataAddress);
    }
    let ok = (0..quantity).all(|i| {
        let access = map.access(table, start + i);
        if write {
            access.writable()
        } else {
            access.readable()
        }
    });
    if ok {
        Ok(())
    } else {
        Err(Exception::IllegalDataAddress)
    }
}

async fn execute<M: RegisterMap>(
    map: &mut M,
    function: u8,
    data: &[u8],
    resp: &mut [u8; MAX_PDU],
) -> Result<usize, Exception> {
    resp[0] = function;
    match function {
        READ_COILS | READ_DISCRETE_INPUTS => {
            let (start, quantity) = fixed_request(data)?;
            if !(1..=MAX_READ_BITS).contains(&quantity) {
                return Err(Exception::IllegalDataValue);
            }
            check_range(map, Table::Bits, start, quantity, false)?;
            let bytes = usize::from(quantity).div_ceil(8);
            resp[1] = bytes as u8;
            resp[2..2 + bytes].fill(0);
            for i in 0..quantity {
                if map.read(Table::Bits, start + i) != 0 {
                    resp[2 + usize::from(i / 8)] |= 1 << (i % 8);
                }
            }
            Ok(2 + bytes)
        }
        READ_HOLDING_REGISTERS | READ_INPUT_REGISTERS => {
            let (start, quantity) = fixed_request(data)?;
            if !(1..=MAX_READ_REGISTERS).contains(&quantity) {
                return Err(Exception::IllegalDataValue);
            }
            check_range(map, Table::Registers, start, quantity, false)?;
            resp[1] = (2 * quantity) as u8;
            for i in 0..quantity {
                let at = 2 + 2 * usize::from(i);
                resp[at..at + 2].copy_from_slice(&map.read(Table::Registers, start + i).to_be_bytes());
            }
            Ok(2 + 2 * usize::from(quantity))
        }
        WRITE_SINGLE_COIL => {
            let (addr, value) = fixed_request(data)?;
            let bit = match value {
                0xFF00 => 1u8,
                0x0000 => 0u8,
                _ => return Err(Exception::IllegalDataValue),
            };
            check_range(map, Table::Bits, addr, 1, true)?;
            let packed = [bit];
            write(map, addr, &WriteValues::bits(&packed, 1)).await?;
            resp[1..5].copy_from_slice(&data[..4]);
            Ok(5)
        }
        WRITE_SINGLE_REGISTER => {
            let (addr, _) = fixed_request(data)?;
            check_range(map, Table::Registers, addr, 1, true)?;
            write(map, addr, &WriteValues::registers(&data[2..4])).await?;
            resp[1..5].copy_from_slice(&data[..4]);
            Ok(5)
        }
        WRITE_MULTIPLE_COILS | WRITE_MULTIPLE_REGISTERS => {
            // start(2) quantity(2) byte count(1) values(byte count)
            if data.len() < 5 {
                return Err(Exception::IllegalDataValue);
            }
            let start = be16(data, 0);
            let quantity = be16(data, 2);
            let byte_count = usize::from(data[4]);
            let values = &data[5..];
            let (table, limit, expected) = if function == WRITE_MULTIPLE_COILS {
                (Table::Bits, MAX_WRITE_BITS, usize::from(quantity).div_ceil(8))
            } else {
                (Table::Registers, MAX_WRITE_REGISTERS, 2 * usize::from(quantity))
            };
            if !(1..=limit).contains(&quantity) || byte_count != expected || values.len() != byte_count {
                return Err(Exception::IllegalDataValue);
            }
            check_range(map, table, start, quantity, true)?;
            let values = match table {
                Table::Bits => WriteValues::bits(values, quantity),
                Table::Registers => WriteValues::registers(values),
            };
            write(map, start, &values).await?;
            resp[1..5].copy_from_slice(&data[..4]);
            Ok(5)
        }
        _ => Err(Exception::IllegalFunction),
    }
}

/// The four-byte body shared by codes 01-06: two big-endian words, nothing more.
fn fixed_request(data: &[u8]) -> Result<(u16, u16), Exception> {
    if data.len() != 4 {
        return Err(Exception::IllegalDataValue);
    }
    Ok((be16(data, 0), be16(data, 2)))
}

async fn write<M: RegisterMap>(map: &mut M, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
    map.validate(start, values)?;
    map.apply(start, values).await
}
