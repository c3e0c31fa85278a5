//! Diagnostics registers of both modules (extensions §1), read-only.

use crate::Word;

/// 40241: module status (bits below).
pub const REG_MODULE_STATUS: u16 = 0x00F0;
/// 40242-40243: seconds since start, 32 bits, low word first.
pub const REG_UPTIME: u16 = 0x00F1;
/// 40244: reset cause ([`reset_cause`]).
pub const REG_RESET_CAUSE: u16 = 0x00F3;
/// 40245: Modbus/TCP clients connected now.
pub const REG_CONNECTIONS: u16 = 0x00F4;
/// 40246-40247: Modbus requests answered since start, 32 bits, low word first.
pub const REG_REQUESTS: u16 = 0x00F5;
/// 40248: exception responses sent since start, 16 bits, wrapping.
pub const REG_EXCEPTIONS: u16 = 0x00F7;

/// Module status bits.
pub mod status {
    /// 8318: the ADC does not answer or a conversion timed out; 8350: input samples were lost
    /// since the last read of the module status.
    pub const FRONT_END_FAULT: u16 = 1 << 0;
    /// 8318: the cold-junction sensor cannot be read.
    pub const CJC_FAULT: u16 = 1 << 1;
    /// The last settings commit failed.
    pub const STORE_FAULT: u16 = 1 << 2;
    /// This run started after a watchdog reset.
    pub const WATCHDOG_RESET: u16 = 1 << 3;
    /// 8350: the host watchdog tripped (extensions §3).
    pub const HOST_WATCHDOG: u16 = 1 << 4;
    /// The inputs are not valid yet (the first acquisition is pending).
    pub const INPUTS_PENDING: u16 = 1 << 5;
    /// Every bit with a meaning, and its name.
    pub const NAMES: [(u16, &str); 6] = [
        (FRONT_END_FAULT, "front-end fault"),
        (CJC_FAULT, "cold-junction fault"),
        (STORE_FAULT, "settings store fault"),
        (WATCHDOG_RESET, "started after a watchdog reset"),
        (HOST_WATCHDOG, "host watchdog tripped"),
        (INPUTS_PENDING, "inputs not valid yet"),
    ];
}

/// Reset cause values (register 40244).
pub mod reset_cause {
    /// Power-on.
    pub const POWER_ON: u16 = 0;
    /// Watchdog.
    pub const WATCHDOG: u16 = 1;
    /// Software restart (restart command, firmware update).
    pub const SOFTWARE: u16 = 2;
    /// Reset pin.
    pub const PIN: u16 = 3;
    /// Brown-out.
    pub const BROWN_OUT: u16 = 4;
    /// The board cannot tell.
    pub const UNKNOWN: u16 = 0xFFFF;

    /// The name of a reset cause value.
    pub fn name(value: u16) -> &'static str {
        match value {
            POWER_ON => "power-on",
            WATCHDOG => "watchdog",
            SOFTWARE => "software restart",
            PIN => "reset pin",
            BROWN_OUT => "brown-out",
            _ => "unknown",
        }
    }
}

/// One diagnostics register.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Diag {
    /// Module status.
    Status,
    /// A word of the uptime.
    Uptime(Word),
    /// Reset cause.
    ResetCause,
    /// Clients connected.
    Connections,
    /// A word of the requests answered.
    Requests(Word),
    /// Exceptions sent.
    Exceptions,
}

/// The diagnostics register at `addr` (4X table), if it is one.
pub fn decode(addr: u16) -> Option<Diag> {
    Some(match addr {
        REG_MODULE_STATUS => Diag::Status,
        a if (REG_UPTIME..REG_UPTIME + 2).contains(&a) => Diag::Uptime(Word::of(a - REG_UPTIME)),
        REG_RESET_CAUSE => Diag::ResetCause,
        REG_CONNECTIONS => Diag::Connections,
        a if (REG_REQUESTS..REG_REQUESTS + 2).contains(&a) => Diag::Requests(Word::of(a - REG_REQUESTS)),
        REG_EXCEPTIONS => Diag::Exceptions,
        _ => return None,
    })
}

impl Diag {
    /// The register's PDU address.
    pub fn addr(self) -> u16 {
        match self {
            Diag::Status => REG_MODULE_STATUS,
            Diag::Uptime(w) => REG_UPTIME + w.offset(),
            Diag::ResetCause => REG_RESET_CAUSE,
            Diag::Connections => REG_CONNECTIONS,
            Diag::Requests(w) => REG_REQUESTS + w.offset(),
            Diag::Exceptions => REG_EXCEPTIONS,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_eight_registers_of_extensions_1() {
        let mapped: std::vec::Vec<u16> = (0..=u16::MAX).filter(|a| decode(*a).is_some()).collect();
        assert_eq!(mapped, (40241..=40248).map(|r| r - 40001).collect::<std::vec::Vec<_>>());
        for a in mapped {
            assert_eq!(decode(a).map(Diag::addr), Some(a));
        }
    }
}
