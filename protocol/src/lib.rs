//! What crosses the wire between a RemoDAQ-8300 module and a PC, in one `no_std` crate with no
//! hardware and no firmware in it: the Modbus tables and register addresses of both modules
//! with their typed decoding ([`m8318::decode`], [`m8350::decode`]), the data formats (input
//! types and scaling, 32-bit words, CJC offset), the network settings, and the discovery
//! codec. The firmware's register maps and the `remodaq` utility both build on it, so they
//! cannot disagree about an address.
#![no_std]
#![warn(missing_docs)]

#[cfg(any(test, feature = "client"))]
extern crate std;

pub mod access;
pub mod auth;
pub mod diag;
pub mod discovery;
pub mod m8318;
pub mod m8350;
pub mod net;
pub mod resources;
mod status;
pub mod update;
pub mod web;
pub mod x509;

/// The two Modbus data tables of the RemoDAQ modules. Codes 01/02/05/15 use `Bits` (0X),
/// codes 03/04/06/16 use `Registers` (4X).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Table {
    /// 0X table: one bit per address.
    Bits,
    /// 4X table: one 16-bit word per address.
    Registers,
}

/// What an address allows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Access {
    /// Not mapped.
    None,
    /// Read only.
    Read,
    /// Write only (reads answer exception 02).
    Write,
    /// Read and write.
    ReadWrite,
}

impl Access {
    /// Reads are allowed.
    pub fn readable(self) -> bool {
        matches!(self, Access::Read | Access::ReadWrite)
    }
    /// Writes are allowed.
    pub fn writable(self) -> bool {
        matches!(self, Access::Write | Access::ReadWrite)
    }
}

/// Identity registers common to both modules (spec §2.1, §3.2).
pub mod identity {
    /// 40211: module name (8318h / 8350h).
    pub const REG_NAME: u16 = 0x00D2;
    /// 40213: firmware version.
    pub const REG_VERSION: u16 = 0x00D4;
    /// Firmware version of this release, reported in 40213: A100h. A test image of another
    /// version (docs/update.md) is built with `REMODAQ_FIRMWARE_VERSION`, which the image crate
    /// reads (boards/update-key.rs) and hands to the runtime (`remodaq_shared::identity`).
    pub const FIRMWARE_VERSION: u16 = 0xA100;
    /// Security counter (anti-rollback) of this release, compiled into the image's identity
    /// (`update::Identity`, which the bootloaders compare before a swap) and signed into its
    /// header by `remodaq sign`: raise it when a release fixes a vulnerability, so that modules
    /// running it refuse every older image. A test image is built with another counter by
    /// `REMODAQ_SECURITY_COUNTER` (boards/update-key.rs).
    pub const SECURITY_COUNTER: u32 = 0;
}

/// One word of a 32-bit value: the low word comes first.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Word {
    /// Bits 0-15.
    Low,
    /// Bits 16-31.
    High,
}

impl Word {
    /// The word at `offset` (0 or 1, or any even / odd offset) from a value's first register.
    pub fn of(offset: u16) -> Self {
        if offset.is_multiple_of(2) {
            Word::Low
        } else {
            Word::High
        }
    }

    /// The word's offset from the value's first register.
    pub fn offset(self) -> u16 {
        match self {
            Word::Low => 0,
            Word::High => 1,
        }
    }

    /// This word of `value`.
    pub fn get(self, value: u32) -> u16 {
        match self {
            Word::Low => value as u16,
            Word::High => (value >> 16) as u16,
        }
    }

    /// `value` with this word replaced by `word`.
    pub fn set(self, value: u32, word: u16) -> u32 {
        match self {
            Word::Low => (value & 0xFFFF_0000) | u32::from(word),
            Word::High => (value & 0xFFFF) | u32::from(word) << 16,
        }
    }
}

/// The Modbus/TCP port of a module with factory settings.
pub const MODBUS_PORT: u16 = 8000;

/// The 32-bit value of a low word and the word after it (spec §3.2: low word first).
pub fn u32_low_first(low: u16, high: u16) -> u32 {
    u32::from(low) | u32::from(high) << 16
}

/// The two words of a 32-bit value, low word first.
pub fn words_low_first(value: u32) -> [u16; 2] {
    [value as u16, (value >> 16) as u16]
}
