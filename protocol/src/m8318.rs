//! The RemoDAQ-8318's Modbus view (spec §2): registers, input types (§2.2) and the
//! 0000h..FFFFh data format (§2.3), the CJC offset encoding (§2.4).

use crate::diag::{self, Diag};
use crate::identity::{REG_NAME, REG_VERSION};
use crate::{Access, Table};

/// Module name register value (40211).
pub const MODULE_NAME: u16 = 0x8318;
/// Model string.
pub const MODEL: &str = "RemoDAQ-8318";
/// Analog input channels.
pub const CHANNELS: usize = 8;

/// 40001 + n: channel n value.
pub const REG_VALUE: u16 = 0x0000;
/// 40009: cold-junction temperature (signed, 0.01 °C).
pub const REG_CJC: u16 = 0x0008;
/// 40201: input type code.
pub const REG_INPUT_TYPE: u16 = 0x00C8;
/// 40216: CJC offset.
pub const REG_CJC_OFFSET: u16 = 0x00D7;
/// 40221: channel enable mask.
pub const REG_ENABLE_MASK: u16 = 0x00DC;
/// 40225 + n: channel n status ([`ChannelStatus`], extensions §2).
pub const REG_STATUS: u16 = 0x00E0;
/// 40233: open-input value (extensions §2): 0 upscale (FFFFh), 1 downscale (0000h).
pub const REG_OPEN_VALUE: u16 = 0x00E8;

/// Why a channel reads what it reads (registers 40225-40232, extensions §2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ChannelStatus {
    /// The value is a measurement inside the range.
    #[default]
    Ok = 0,
    /// Nothing connected (burnt-out thermocouple): the open-input value.
    Open = 1,
    /// Above the range: FFFFh.
    Over = 2,
    /// Below the range: 0000h.
    Under = 3,
    /// The channel is disabled: 0000h.
    Disabled = 4,
    /// The conversion failed (the ADC does not answer or timed out): FFFFh.
    FrontEndFault = 5,
    /// A thermocouple channel without a valid cold-junction reading: FFFFh.
    CjcFault = 6,
}

impl ChannelStatus {
    /// Every status, by register value.
    pub const ALL: [ChannelStatus; 7] = [
        ChannelStatus::Ok,
        ChannelStatus::Open,
        ChannelStatus::Over,
        ChannelStatus::Under,
        ChannelStatus::Disabled,
        ChannelStatus::FrontEndFault,
        ChannelStatus::CjcFault,
    ];

    /// The status of a register value.
    pub fn from_register(v: u16) -> Option<Self> {
        Self::ALL.get(usize::from(v)).copied()
    }

    /// A short name.
    pub fn name(self) -> &'static str {
        match self {
            ChannelStatus::Ok => "ok",
            ChannelStatus::Open => "open",
            ChannelStatus::Over => "over range",
            ChannelStatus::Under => "under range",
            ChannelStatus::Disabled => "disabled",
            ChannelStatus::FrontEndFault => "front-end fault",
            ChannelStatus::CjcFault => "cold-junction fault",
        }
    }
}

/// One register of the 8318.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reg {
    /// Channel n value (0..8).
    Value(u8),
    /// Cold-junction temperature.
    Cjc,
    /// Input type code.
    InputType,
    /// CJC offset.
    CjcOffset,
    /// Channel enable mask.
    EnableMask,
    /// Channel n status (0..8).
    Status(u8),
    /// Open-input value.
    OpenValue,
    /// Module name.
    Name,
    /// Firmware version.
    Version,
    /// A diagnostics register (extensions §1).
    Diag(Diag),
}

/// The register at `addr` of `table`; `None` where nothing is mapped (the 8318 has no bits).
pub fn decode(table: Table, addr: u16) -> Option<Reg> {
    if table == Table::Bits {
        return None;
    }
    Some(match addr {
        a if a < REG_VALUE + CHANNELS as u16 => Reg::Value((a - REG_VALUE) as u8),
        REG_CJC => Reg::Cjc,
        REG_INPUT_TYPE => Reg::InputType,
        REG_CJC_OFFSET => Reg::CjcOffset,
        REG_ENABLE_MASK => Reg::EnableMask,
        a if (REG_STATUS..REG_STATUS + CHANNELS as u16).contains(&a) => Reg::Status((a - REG_STATUS) as u8),
        REG_OPEN_VALUE => Reg::OpenValue,
        REG_NAME => Reg::Name,
        REG_VERSION => Reg::Version,
        a => Reg::Diag(diag::decode(a)?),
    })
}

impl Reg {
    /// The register's PDU address (4X table).
    pub fn addr(self) -> u16 {
        match self {
            Reg::Value(n) => REG_VALUE + u16::from(n),
            Reg::Cjc => REG_CJC,
            Reg::InputType => REG_INPUT_TYPE,
            Reg::CjcOffset => REG_CJC_OFFSET,
            Reg::EnableMask => REG_ENABLE_MASK,
            Reg::Status(n) => REG_STATUS + u16::from(n),
            Reg::OpenValue => REG_OPEN_VALUE,
            Reg::Name => REG_NAME,
            Reg::Version => REG_VERSION,
            Reg::Diag(d) => d.addr(),
        }
    }

    /// What the register allows.
    pub fn access(self) -> Access {
        match self {
            Reg::InputType | Reg::CjcOffset | Reg::EnableMask | Reg::OpenValue => Access::ReadWrite,
            _ => Access::Read,
        }
    }
}

/// The access of `addr` in `table`.
pub fn access(table: Table, addr: u16) -> Access {
    decode(table, addr).map_or(Access::None, Reg::access)
}

/// Largest CJC offset magnitude, 0.01 °C (spec §2.4: -50.00 .. +50.00 °C).
pub const CJC_OFFSET_LIMIT: i16 = 5000;

/// The CJC offset (0.01 °C) of a register value: 0000h..AFFFh positive, B000h..FFFFh
/// negative (spec §2.4); `None` outside ±50.00 °C.
pub fn cjc_offset_from_register(raw: u16) -> Option<i16> {
    let value = if raw <= 0xAFFF { i32::from(raw) } else { i32::from(raw) - 0x1_0000 };
    (value.abs() <= i32::from(CJC_OFFSET_LIMIT)).then_some(value as i16)
}

/// The register value of a CJC offset (two's complement, which matches the encoding above).
pub fn cjc_offset_to_register(offset: i16) -> u16 {
    offset as u16
}

/// The thermocouple types of spec §2.2 (the reference functions are the module's).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TcType {
    /// Pt-30%Rh / Pt-6%Rh.
    B,
    /// W-5%Re / W-26%Re.
    C,
    /// Chromel / constantan.
    E,
    /// Iron / constantan.
    J,
    /// Chromel / alumel.
    K,
    /// Chromel / copel (GOST).
    L,
    /// Copper / copel (GOST).
    M,
    /// Nicrosil / nisil.
    N,
    /// Pt-13%Rh / Pt.
    R,
    /// Pt-10%Rh / Pt.
    S,
    /// Copper / constantan.
    T,
}

impl TcType {
    /// All types, in type-code order of spec §2.2.
    pub const ALL: [TcType; 11] = [
        TcType::J,
        TcType::K,
        TcType::T,
        TcType::E,
        TcType::R,
        TcType::S,
        TcType::B,
        TcType::N,
        TcType::C,
        TcType::L,
        TcType::M,
    ];

    /// The type's letter.
    pub fn letter(self) -> &'static str {
        match self {
            TcType::B => "B",
            TcType::C => "C",
            TcType::E => "E",
            TcType::J => "J",
            TcType::K => "K",
            TcType::L => "L",
            TcType::M => "M",
            TcType::N => "N",
            TcType::R => "R",
            TcType::S => "S",
            TcType::T => "T",
        }
    }
}

/// What an input type measures.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Kind {
    /// A voltage, engineering unit mV.
    Voltage,
    /// A current through the shunt, engineering unit mA.
    Current,
    /// A thermocouple, engineering unit °C.
    Thermocouple(TcType),
}

/// One input type code with its engineering range.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InputType {
    /// The type code of register 40201.
    pub code: u8,
    /// What is measured.
    pub kind: Kind,
    /// Low end of the engineering range (mV, mA or °C).
    pub lo: f64,
    /// High end of the engineering range (mV, mA or °C).
    pub hi: f64,
}

const fn voltage(code: u8, mv: f64) -> InputType {
    InputType { code, kind: Kind::Voltage, lo: -mv, hi: mv }
}

const fn tc(code: u8, tc: TcType, lo: f64, hi: f64) -> InputType {
    InputType { code, kind: Kind::Thermocouple(tc), lo, hi }
}

/// Every input type of spec §2.2, in code order.
pub const INPUT_TYPES: [InputType; 18] = [
    voltage(0x00, 15.0),
    voltage(0x01, 50.0),
    voltage(0x02, 100.0),
    voltage(0x03, 500.0),
    voltage(0x04, 1000.0),
    voltage(0x05, 2500.0),
    InputType { code: 0x06, kind: Kind::Current, lo: -20.0, hi: 20.0 },
    tc(0x0E, TcType::J, -200.0, 1100.0),
    tc(0x0F, TcType::K, -250.0, 1400.0),
    tc(0x10, TcType::T, -250.0, 400.0),
    tc(0x11, TcType::E, -250.0, 900.0),
    tc(0x12, TcType::R, 0.0, 1750.0),
    tc(0x13, TcType::S, 0.0, 1750.0),
    tc(0x14, TcType::B, 0.0, 1800.0),
    tc(0x15, TcType::N, -250.0, 1300.0),
    tc(0x16, TcType::C, 0.0, 2310.0),
    tc(0x17, TcType::L, -200.0, 800.0),
    tc(0x18, TcType::M, -200.0, 100.0),
];

impl InputType {
    /// The input type of a code; `None` for codes not in spec §2.2.
    pub fn from_code(code: u8) -> Option<Self> {
        INPUT_TYPES.iter().copied().find(|t| t.code == code)
    }

    /// The thermocouple type, if this is one.
    pub fn thermocouple(&self) -> Option<TcType> {
        match self.kind {
            Kind::Thermocouple(tc) => Some(tc),
            _ => None,
        }
    }

    /// The register value of `x` (engineering units) on this type's range.
    pub fn raw(&self, x: f64) -> u16 {
        scale(x, self.lo, self.hi)
    }

    /// The engineering value of a register value on this type's range.
    pub fn value(&self, raw: u16) -> f64 {
        unscale(raw, self.lo, self.hi)
    }
}

/// raw = round((x - lo) / (hi - lo) * 65535), clamped to 0000h..FFFFh; NaN reads FFFFh.
pub fn scale(x: f64, lo: f64, hi: f64) -> u16 {
    let r = libm::round((x - lo) / (hi - lo) * 65535.0);
    if r.is_nan() || r >= 65535.0 {
        0xFFFF
    } else if r <= 0.0 {
        0
    } else {
        r as u16
    }
}

/// The engineering value of a register value (for tools and tests).
pub fn unscale(raw: u16, lo: f64, hi: f64) -> f64 {
    lo + f64::from(raw) / 65535.0 * (hi - lo)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_address_decodes_to_the_register_that_names_it() {
        for addr in 0..=u16::MAX {
            assert_eq!(decode(Table::Bits, addr), None);
            if let Some(reg) = decode(Table::Registers, addr) {
                assert_eq!(reg.addr(), addr, "{reg:?}");
            }
        }
        // Spec §2.1, by 4X number.
        let mapped: [(u16, Access); 18] = [
            (40225, Access::Read),
            (40232, Access::Read),
            (40233, Access::ReadWrite),
            (40234, Access::None),
            (40001, Access::Read),
            (40008, Access::Read),
            (40009, Access::Read),
            (40201, Access::ReadWrite),
            (40211, Access::Read),
            (40213, Access::Read),
            (40216, Access::ReadWrite),
            (40221, Access::ReadWrite),
            (40010, Access::None),
            (40200, Access::None),
            (40212, Access::None),
            (40214, Access::None),
            (40222, Access::None),
            (40202, Access::None),
        ];
        for (reg4x, want) in mapped {
            assert_eq!(access(Table::Registers, reg4x - 40001), want, "{reg4x}");
        }
    }

    #[test]
    fn cjc_offset_encoding() {
        assert_eq!(cjc_offset_from_register(0), Some(0));
        assert_eq!(cjc_offset_from_register(5000), Some(5000));
        assert_eq!(cjc_offset_from_register(5001), None);
        assert_eq!(cjc_offset_from_register(0xAFFF), None);
        assert_eq!(cjc_offset_from_register(0xB000), None);
        assert_eq!(cjc_offset_from_register(0xFFFF), Some(-1));
        assert_eq!(cjc_offset_from_register(0x10000u32.wrapping_sub(5000) as u16), Some(-5000));
        assert_eq!(cjc_offset_from_register(0x10000u32.wrapping_sub(5001) as u16), None);
        for o in [-5000i16, -1, 0, 1, 5000] {
            assert_eq!(cjc_offset_from_register(cjc_offset_to_register(o)), Some(o));
        }
    }
}
