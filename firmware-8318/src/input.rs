//! Input types (spec §2.2) and the 0000h..FFFFh data format (spec §2.3).

use crate::thermocouple::TcType;

/// The current input's shunt: ±20 mA gives ±2.5 V at the ADC.
pub const SHUNT_OHMS: f64 = 125.0;
/// Span the front end must cover for thermocouples, mV (the largest emf of any type over its
/// module range is under 70 mV, minus a cold junction below 0 °C).
pub const THERMOCOUPLE_SPAN_MV: f64 = 100.0;

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

    /// The full-scale voltage at the terminals the front end must cover, mV.
    pub fn span_mv(&self) -> f64 {
        match self.kind {
            Kind::Voltage => self.hi,
            Kind::Current => self.hi * SHUNT_OHMS,
            Kind::Thermocouple(_) => THERMOCOUPLE_SPAN_MV,
        }
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

/// The engineering value of a register value (for tools and tests): the middle of its step.
pub fn unscale(raw: u16, lo: f64, hi: f64) -> f64 {
    lo + f64::from(raw) / 65535.0 * (hi - lo)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaling_edges() {
        let k = InputType::from_code(0x0F).unwrap();
        assert_eq!(k.raw(-250.0), 0x0000);
        assert_eq!(k.raw(1400.0), 0xFFFF);
        assert_eq!(k.raw(-300.0), 0x0000, "under range");
        assert_eq!(k.raw(1500.0), 0xFFFF, "over range");
        assert_eq!(k.raw(f64::NAN), 0xFFFF);
        // Mid-scale of a symmetric range and one step above the bottom.
        let v = InputType::from_code(0x05).unwrap();
        assert_eq!(v.raw(0.0), 0x8000); // 32767.5 rounds up
        assert_eq!(v.raw(-2500.0 + 5000.0 / 65535.0), 1);
        assert_eq!(v.raw(-2500.0 + 0.49 * 5000.0 / 65535.0), 0);
        assert_eq!(v.raw(2500.0 - 0.49 * 5000.0 / 65535.0), 0xFFFF);
        assert_eq!(v.raw(2500.0 - 0.51 * 5000.0 / 65535.0), 0xFFFE);
    }

    #[test]
    fn codes() {
        assert!(InputType::from_code(0x07).is_none());
        assert!(InputType::from_code(0x0D).is_none());
        assert!(InputType::from_code(0x19).is_none());
        assert_eq!(InputType::from_code(0x06).unwrap().span_mv(), 2500.0);
        let codes: [u8; 18] = INPUT_TYPES.map(|t| t.code);
        assert_eq!(codes, [0, 1, 2, 3, 4, 5, 6, 0x0E, 0x0F, 0x10, 0x11, 0x12, 0x13, 0x14, 0x15, 0x16, 0x17, 0x18]);
    }
}
