//! Input types (spec §2.2) and the 0000h..FFFFh data format (spec §2.3), from the protocol
//! crate, and what the front end needs to know of them.

pub use remodaq_protocol::m8318::{scale, unscale, InputType, Kind, INPUT_TYPES};

/// The current input's shunt, ohm: ±20 mA gives ±2.0 V at the ADC, 80 % of the AD7124-8's
/// ±2.5 V range at gain 1, so 20 mA is not at the converter's saturation and over-range
/// currents up to 25 mA are still measured (and read FFFFh, above the range). A 125 ohm shunt
/// would put 20 mA exactly at full scale (review of the STM32 board).
pub const SHUNT_OHMS: f64 = 100.0;

/// Span the front end must cover for thermocouples, mV (the largest emf of any type over its
/// module range is under 70 mV, minus a cold junction below 0 °C).
pub const THERMOCOUPLE_SPAN_MV: f64 = 100.0;

/// The full-scale voltage at the terminals the front end must cover for an input type, mV.
pub fn span_mv(t: &InputType) -> f64 {
    match t.kind {
        Kind::Voltage => t.hi,
        Kind::Current => t.hi * SHUNT_OHMS,
        Kind::Thermocouple(_) => THERMOCOUPLE_SPAN_MV,
    }
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
        assert_eq!(span_mv(&InputType::from_code(0x06).unwrap()), 2000.0, "20 mA through 100 ohm");
        let codes: [u8; 18] = INPUT_TYPES.map(|t| t.code);
        assert_eq!(codes, [0, 1, 2, 3, 4, 5, 6, 0x0E, 0x0F, 0x10, 0x11, 0x12, 0x13, 0x14, 0x15, 0x16, 0x17, 0x18]);
    }
}
