//! The RemoDAQ-8350's Modbus view (spec §3.1-3.2): bits, registers and their typed decoding,
//! and the DI / DO mode values.

use crate::diag::{self, Diag};
use crate::identity::{REG_NAME, REG_VERSION};
pub use crate::Word;
use crate::{Access, Table};

/// Module name register value (40211).
pub const MODULE_NAME: u16 = 0x8350;
/// Model string.
pub const MODEL: &str = "RemoDAQ-8350";
/// Digital inputs.
pub const DI_CHANNELS: usize = 12;
/// Digital outputs.
pub const DO_CHANNELS: usize = 6;

const DI: u16 = DI_CHANNELS as u16;
const DO: u16 = DO_CHANNELS as u16;

/// 0X: DI n state.
pub const BIT_DI: u16 = 0x00;
/// 0X: DO n.
pub const BIT_DO: u16 = 0x10;
/// 0X: DI n counter run / clear / overflow / latch at `BIT_COUNTER + 4n + 0..3`.
pub const BIT_COUNTER: u16 = 0x20;
/// 4X: DI n counter, 32-bit low word first.
pub const REG_COUNTER: u16 = 0x00;
/// 4X: DO n pulse low width, high width, count, extra pulses (32-bit, 12 registers each).
pub const REG_PULSE: u16 = 0x18;
/// 4X: DI n mode.
pub const REG_DI_MODE: u16 = 0x100;
/// 4X: DO n mode.
pub const REG_DO_MODE: u16 = 0x110;
/// 4X: all DI.
pub const REG_ALL_DI: u16 = 0x12C;
/// 4X: all DO.
pub const REG_ALL_DO: u16 = 0x12E;
/// 4X: host watchdog timeout, 0.1 s, 0 off (extensions §3).
pub const REG_WD_TIMEOUT: u16 = 0x130;
/// 4X: safe output values, bit n = DOn.
pub const REG_SAFE_VALUES: u16 = 0x131;
/// 4X: host watchdog mode ([`wd_mode`]).
pub const REG_WD_MODE: u16 = 0x132;
/// 4X: host watchdog status: bit 0 tripped; write 0 to clear.
pub const REG_WD_STATUS: u16 = 0x133;
/// 4X: power-on output values, bit n = DOn.
pub const REG_POWER_ON: u16 = 0x134;
/// Largest watchdog timeout, 0.1 s (10 min).
pub const WD_TIMEOUT_MAX: u16 = 6000;

/// Bits of the watchdog mode register (40307).
pub mod wd_mode {
    /// 1: only write requests feed the watchdog; 0: any request.
    pub const WRITES_ONLY: u16 = 1 << 0;
    /// 1: the next feeding request ends the safe state; 0: only writing 0 to 40308.
    pub const AUTO_CLEAR: u16 = 1 << 1;
    /// Bits with a meaning.
    pub const ALL: u16 = WRITES_ONLY | AUTO_CLEAR;
}

/// The four 32-bit pulse fields of each output, in register order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PulseField {
    /// Low width, 0.1 ms (40025 + 2n).
    Low = 0,
    /// High width, 0.1 ms (40037 + 2n).
    High = 1,
    /// Pulse count, 0 = continuous (40049 + 2n).
    Count = 2,
    /// Extra pulses (40061 + 2n).
    Extra = 3,
}

/// One address of the 8350 (channel numbers are in range by construction of [`decode`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Point {
    /// Bit: DI n state.
    DiState(u8),
    /// Bit: DO n.
    Do(u8),
    /// Bit: DI n counter run (1) / stop (0).
    CounterRun(u8),
    /// Bit: DI n counter clear (write 1; reads 0).
    CounterClear(u8),
    /// Bit: DI n counter overflow flag (cleared by reading it or writing 0).
    Overflow(u8),
    /// Bit: DI n latch flag (cleared by reading it or writing 0).
    Latch(u8),
    /// Register: one word of DI n's counter.
    Counter(u8, Word),
    /// Register: one word of a pulse field of DO n.
    Pulse(PulseField, u8, Word),
    /// Register: DI n mode.
    DiMode(u8),
    /// Register: DO n mode.
    DoMode(u8),
    /// Register: all DI.
    AllDi,
    /// Register: all DO.
    AllDo,
    /// Register: module name.
    Name,
    /// Register: firmware version.
    Version,
    /// Register: a diagnostics register (extensions §1).
    Diag(Diag),
    /// Register: host watchdog timeout.
    WatchdogTimeout,
    /// Register: safe output values.
    SafeValues,
    /// Register: host watchdog mode.
    WatchdogMode,
    /// Register: host watchdog status.
    WatchdogStatus,
    /// Register: power-on output values.
    PowerOnValues,
}

/// The point at `addr` of `table`; `None` where nothing is mapped.
pub fn decode(table: Table, addr: u16) -> Option<Point> {
    let n = |base: u16, per: u16| ((addr - base) / per) as u8;
    Some(match table {
        Table::Bits => match addr {
            a if (BIT_DI..BIT_DI + DI).contains(&a) => Point::DiState(n(BIT_DI, 1)),
            a if (BIT_DO..BIT_DO + DO).contains(&a) => Point::Do(n(BIT_DO, 1)),
            a if (BIT_COUNTER..BIT_COUNTER + 4 * DI).contains(&a) => {
                let ch = n(BIT_COUNTER, 4);
                match (a - BIT_COUNTER) % 4 {
                    0 => Point::CounterRun(ch),
                    1 => Point::CounterClear(ch),
                    2 => Point::Overflow(ch),
                    _ => Point::Latch(ch),
                }
            }
            _ => return None,
        },
        Table::Registers => match addr {
            a if (REG_COUNTER..REG_COUNTER + 2 * DI).contains(&a) => {
                Point::Counter(n(REG_COUNTER, 2), Word::of(a - REG_COUNTER))
            }
            a if (REG_PULSE..REG_PULSE + 8 * DO).contains(&a) => {
                let i = a - REG_PULSE;
                let field = match i / (2 * DO) {
                    0 => PulseField::Low,
                    1 => PulseField::High,
                    2 => PulseField::Count,
                    _ => PulseField::Extra,
                };
                Point::Pulse(field, (i % (2 * DO) / 2) as u8, Word::of(i))
            }
            a if (REG_DI_MODE..REG_DI_MODE + DI).contains(&a) => Point::DiMode(n(REG_DI_MODE, 1)),
            a if (REG_DO_MODE..REG_DO_MODE + DO).contains(&a) => Point::DoMode(n(REG_DO_MODE, 1)),
            REG_ALL_DI => Point::AllDi,
            REG_ALL_DO => Point::AllDo,
            REG_NAME => Point::Name,
            REG_VERSION => Point::Version,
            REG_WD_TIMEOUT => Point::WatchdogTimeout,
            REG_SAFE_VALUES => Point::SafeValues,
            REG_WD_MODE => Point::WatchdogMode,
            REG_WD_STATUS => Point::WatchdogStatus,
            REG_POWER_ON => Point::PowerOnValues,
            a => Point::Diag(diag::decode(a)?),
        },
    })
}

impl Point {
    /// The table and PDU address of the point.
    pub fn addr(self) -> (Table, u16) {
        let ch = |n: u8| u16::from(n);
        match self {
            Point::DiState(n) => (Table::Bits, BIT_DI + ch(n)),
            Point::Do(n) => (Table::Bits, BIT_DO + ch(n)),
            Point::CounterRun(n) => (Table::Bits, BIT_COUNTER + 4 * ch(n)),
            Point::CounterClear(n) => (Table::Bits, BIT_COUNTER + 4 * ch(n) + 1),
            Point::Overflow(n) => (Table::Bits, BIT_COUNTER + 4 * ch(n) + 2),
            Point::Latch(n) => (Table::Bits, BIT_COUNTER + 4 * ch(n) + 3),
            Point::Counter(n, w) => (Table::Registers, REG_COUNTER + 2 * ch(n) + w.offset()),
            Point::Pulse(f, n, w) => (Table::Registers, REG_PULSE + 2 * DO * f as u16 + 2 * ch(n) + w.offset()),
            Point::DiMode(n) => (Table::Registers, REG_DI_MODE + ch(n)),
            Point::DoMode(n) => (Table::Registers, REG_DO_MODE + ch(n)),
            Point::AllDi => (Table::Registers, REG_ALL_DI),
            Point::AllDo => (Table::Registers, REG_ALL_DO),
            Point::Name => (Table::Registers, REG_NAME),
            Point::Version => (Table::Registers, REG_VERSION),
            Point::Diag(d) => (Table::Registers, d.addr()),
            Point::WatchdogTimeout => (Table::Registers, REG_WD_TIMEOUT),
            Point::SafeValues => (Table::Registers, REG_SAFE_VALUES),
            Point::WatchdogMode => (Table::Registers, REG_WD_MODE),
            Point::WatchdogStatus => (Table::Registers, REG_WD_STATUS),
            Point::PowerOnValues => (Table::Registers, REG_POWER_ON),
        }
    }

    /// Whether a write to the point could change an output (refused while the host watchdog
    /// is tripped, extensions §3): the DO bits, all DO, the DO modes and the pulse settings.
    pub fn moves_output(self) -> bool {
        matches!(self, Point::Do(_) | Point::AllDo | Point::DoMode(_) | Point::Pulse(..))
    }

    /// What the point allows.
    pub fn access(self) -> Access {
        match self {
            Point::DiState(_) | Point::Counter(..) | Point::AllDi | Point::Name | Point::Version | Point::Diag(_) => {
                Access::Read
            }
            _ => Access::ReadWrite,
        }
    }
}

/// The access of `addr` in `table`.
pub fn access(table: Table, addr: u16) -> Access {
    decode(table, addr).map_or(Access::None, Point::access)
}

/// DI modes (spec §3.3): the values of registers 40257-40268.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DiMode {
    /// State only.
    Normal = 0,
    /// Counts rising edges while the run bit is 1.
    Counter = 1,
    /// The latch flag is set on a rising edge.
    LatchRising = 2,
    /// The latch flag is set on a falling edge.
    LatchFalling = 3,
    /// Rising edges over a 1 s gate, in Hz.
    Frequency = 4,
}

impl DiMode {
    /// Every mode, by register value.
    pub const ALL: [DiMode; 5] =
        [DiMode::Normal, DiMode::Counter, DiMode::LatchRising, DiMode::LatchFalling, DiMode::Frequency];

    /// The mode of a register value; `None` for values not in spec §3.2.
    pub fn from_register(v: u16) -> Option<Self> {
        Self::ALL.get(usize::from(v)).copied()
    }
}

/// DO modes (spec §3.4): the values of registers 40273-40278.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DoMode {
    /// The DO bit drives the output.
    Normal = 0,
    /// Writing 1 to the DO bit starts a pulse train, 0 stops it.
    Pulse = 1,
}

impl DoMode {
    /// The mode of a register value; `None` for values not in spec §3.2.
    pub fn from_register(v: u16) -> Option<Self> {
        match v {
            0 => Some(DoMode::Normal),
            1 => Some(DoMode::Pulse),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_address_decodes_to_the_point_that_names_it() {
        for table in [Table::Bits, Table::Registers] {
            for addr in 0..=u16::MAX {
                if let Some(point) = decode(table, addr) {
                    assert_eq!(point.addr(), (table, addr), "{point:?}");
                }
            }
        }
    }

    #[test]
    fn spec_addresses() {
        // Spec §3.1 by 0X number, §3.2 by 4X number.
        let bits: [(u16, Option<Point>); 10] = [
            (1, Some(Point::DiState(0))),
            (12, Some(Point::DiState(11))),
            (13, None),
            (17, Some(Point::Do(0))),
            (22, Some(Point::Do(5))),
            (23, None),
            (33, Some(Point::CounterRun(0))),
            (34 + 4 * 11, Some(Point::CounterClear(11))),
            (36 + 4 * 11, Some(Point::Latch(11))),
            (37 + 4 * 11, None),
        ];
        for (n0x, want) in bits {
            assert_eq!(decode(Table::Bits, n0x - 1), want, "0X {n0x}");
        }
        let regs: [(u16, Option<Point>); 19] = [
            (40304, None),
            (40305, Some(Point::WatchdogTimeout)),
            (40306, Some(Point::SafeValues)),
            (40307, Some(Point::WatchdogMode)),
            (40308, Some(Point::WatchdogStatus)),
            (40309, Some(Point::PowerOnValues)),
            (40001, Some(Point::Counter(0, Word::Low))),
            (40024, Some(Point::Counter(11, Word::High))),
            (40025, Some(Point::Pulse(PulseField::Low, 0, Word::Low))),
            (40036, Some(Point::Pulse(PulseField::Low, 5, Word::High))),
            (40037, Some(Point::Pulse(PulseField::High, 0, Word::Low))),
            (40049, Some(Point::Pulse(PulseField::Count, 0, Word::Low))),
            (40061, Some(Point::Pulse(PulseField::Extra, 0, Word::Low))),
            (40072, Some(Point::Pulse(PulseField::Extra, 5, Word::High))),
            (40073, None),
            (40268, Some(Point::DiMode(11))),
            (40278, Some(Point::DoMode(5))),
            (40301, Some(Point::AllDi)),
            (40303, Some(Point::AllDo)),
        ];
        for (n4x, want) in regs {
            assert_eq!(decode(Table::Registers, n4x - 40001), want, "4X {n4x}");
        }
        assert_eq!(access(Table::Registers, 40212 - 40001), Access::None);
        assert_eq!(access(Table::Registers, 40302 - 40001), Access::None);
        assert_eq!(access(Table::Registers, 40213 - 40001), Access::Read);
    }
}
