//! Test helpers shared by the integration tests: a small register map and a scripted transport.
#![allow(dead_code)]

use std::collections::VecDeque;
use std::vec::Vec;

use remodaq_shared::access::AllowList;
use remodaq_shared::modbus::{Access, Exception, RegisterMap, Table, WriteValues};
use remodaq_shared::module::SettingsAccess;
use remodaq_shared::net::{NetConfig, NetRecord};
use remodaq_shared::settings::{RecordReader, RecordWriter, Schema};

/// Bits 0x00..0x20 readable, 0x10..0x16 writable, 0x1000..0x1800 read/write (a block large
/// enough for the longest writes); registers 0x00..0x80 read/write, 0x100 read only, 0x101
/// write only. A register value of 0xBAD fails validation (03); `fail_apply` makes
/// the commit fail (04).
pub struct TestMap {
    pub bits: [bool; 0x20],
    pub block: Vec<bool>,
    pub regs: [u16; 0x80],
    pub fail_apply: bool,
    pub applied: usize,
}

impl Default for TestMap {
    fn default() -> Self {
        Self { bits: [false; 0x20], block: vec![false; 0x800], regs: [0; 0x80], fail_apply: false, applied: 0 }
    }
}

impl RegisterMap for TestMap {
    fn access(&self, table: Table, addr: u16) -> Access {
        match (table, addr) {
            (Table::Bits, 0x10..=0x15) => Access::ReadWrite,
            (Table::Bits, 0x00..=0x1F) => Access::Read,
            (Table::Bits, 0x1000..=0x17FF) => Access::ReadWrite,
            (Table::Registers, 0x00..=0x7F) => Access::ReadWrite,
            (Table::Registers, 0x100) => Access::Read,
            (Table::Registers, 0x101) => Access::Write,
            _ => Access::None,
        }
    }

    fn read(&mut self, table: Table, addr: u16) -> u16 {
        match table {
            Table::Bits if addr >= 0x1000 => u16::from(self.block[usize::from(addr - 0x1000)]),
            Table::Bits => u16::from(self.bits[usize::from(addr)]),
            Table::Registers if addr == 0x100 => 0x8318,
            Table::Registers => self.regs[usize::from(addr)],
        }
    }

    fn validate(&self, _start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        if values.table() == Table::Registers && values.iter().any(|v| v == 0xBAD) {
            return Err(Exception::IllegalDataValue);
        }
        Ok(())
    }

    async fn apply(&mut self, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        if self.fail_apply {
            return Err(Exception::ServerDeviceFailure);
        }
        self.applied += 1;
        for (i, v) in values.iter().enumerate() {
            let addr = usize::from(start) + i;
            match values.table() {
                Table::Bits if addr >= 0x1000 => self.block[addr - 0x1000] = v != 0,
                Table::Bits => self.bits[addr] = v != 0,
                Table::Registers if addr < 0x80 => self.regs[addr] = v,
                Table::Registers => {}
            }
        }
        Ok(())
    }
}

/// A transport that delivers the given segments one `read` at a time, then reports the peer
/// closed; everything written is collected.
pub struct Script {
    pub incoming: VecDeque<Vec<u8>>,
    pub outgoing: Vec<u8>,
}

impl Script {
    pub fn new(segments: &[&[u8]]) -> Self {
        Self { incoming: segments.iter().map(|s| s.to_vec()).collect(), outgoing: Vec::new() }
    }
}

impl embedded_io_async::ErrorType for Script {
    type Error = core::convert::Infallible;
}

impl embedded_io_async::Read for Script {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let Some(mut seg) = self.incoming.pop_front() else { return Ok(0) };
        let n = seg.len().min(buf.len());
        buf[..n].copy_from_slice(&seg[..n]);
        if n < seg.len() {
            self.incoming.push_front(seg.split_off(n));
        }
        Ok(n)
    }
}

impl embedded_io_async::Write for Script {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.outgoing.extend_from_slice(buf);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// Parses a hex string such as "01 04 00 01".
pub fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace().map(|b| u8::from_str_radix(b, 16).expect("hex byte")).collect()
}

/// Settings with what every module has: network, password, allow-list.
#[derive(Clone, Copy, PartialEq, Debug)]
pub struct S {
    pub net: NetConfig,
    pub password: remodaq_shared::password::Credential,
    pub allow: AllowList,
    pub http_port: u16,
    pub update: remodaq_shared::settings::Counter,
}

impl Schema for S {
    const VERSION: u8 = 2;
    fn defaults() -> Self {
        Self {
            net: NetConfig::FACTORY,
            password: remodaq_shared::password::Credential::FACTORY,
            allow: AllowList::EMPTY,
            http_port: remodaq_shared::net::HTTP_PORT,
            update: Default::default(),
        }
    }
    fn unreadable() -> Self {
        Self { password: remodaq_shared::password::LOCKED, ..Self::defaults() }
    }
    fn encode(&self, w: &mut RecordWriter<'_>) {
        self.net.encode(w);
        remodaq_shared::password::encode(&self.password, w);
        remodaq_shared::access::encode(&self.allow, w);
        remodaq_shared::net::encode_http_port(self.http_port, w);
        self.update.encode(w);
    }
    fn decode(version: u8, r: &RecordReader<'_>) -> Self {
        Self {
            net: NetConfig::decode(r),
            password: remodaq_shared::password::decode(version, r),
            allow: remodaq_shared::access::decode(r),
            http_port: remodaq_shared::net::decode_http_port(r),
            update: remodaq_shared::settings::Counter::decode(r),
        }
    }
}

remodaq_shared::impl_common_settings!(S);

/// A register map's copy of the settings in force.
pub struct Live(pub S);

impl SettingsAccess for Live {
    type Settings = S;
    fn settings(&self) -> &S {
        &self.0
    }
    fn committed(&mut self, s: &S) {
        self.0 = *s;
    }
}
