//! Persisted settings of the 8318 (spec §2.1, §1.4).

use remodaq_shared::net::NetConfig;
use remodaq_shared::password::PasswordHash;
use remodaq_shared::settings::{RecordReader, RecordWriter, Schema};

use crate::input::InputType;

/// CJC offset limit: ±50.00 °C in 0.01 °C.
pub const CJC_OFFSET_LIMIT: i16 = 5000;

/// Everything the 8318 keeps in flash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Settings {
    /// Network settings.
    pub net: NetConfig,
    /// Configuration password (network settings, restart).
    pub password: PasswordHash,
    /// Input type code (40201), one of spec §2.2 ([`InputType::from_code`]).
    pub input_type: u8,
    /// CJC offset (40216) in 0.01 °C, within ±[`CJC_OFFSET_LIMIT`].
    pub cjc_offset: i16,
    /// Channel enable mask (40221), bit n = channel n.
    pub enable_mask: u8,
}

mod tag {
    pub const INPUT_TYPE: u8 = 32;
    pub const CJC_OFFSET: u8 = 33;
    pub const ENABLE_MASK: u8 = 34;
}

impl Schema for Settings {
    const VERSION: u8 = 1;

    fn defaults() -> Self {
        // Decision: factory input type 0Fh (type K), all channels enabled, no CJC offset.
        Self {
            net: NetConfig::FACTORY,
            password: PasswordHash::factory(),
            input_type: 0x0F,
            cjc_offset: 0,
            enable_mask: 0xFF,
        }
    }

    fn encode(&self, w: &mut RecordWriter<'_>) {
        self.net.encode(w);
        self.password.encode(w);
        w.put(tag::INPUT_TYPE, &[self.input_type]);
        w.put(tag::CJC_OFFSET, &self.cjc_offset.to_le_bytes());
        w.put(tag::ENABLE_MASK, &[self.enable_mask]);
    }

    fn decode(_version: u8, r: &RecordReader<'_>) -> Self {
        let d = Self::defaults();
        Self {
            net: NetConfig::decode(r),
            password: PasswordHash::decode(r),
            input_type: r
                .array::<1>(tag::INPUT_TYPE)
                .map(|[t]| t)
                .filter(|t| InputType::from_code(*t).is_some())
                .unwrap_or(d.input_type),
            cjc_offset: r
                .array(tag::CJC_OFFSET)
                .map(i16::from_le_bytes)
                .filter(|o| o.abs() <= CJC_OFFSET_LIMIT)
                .unwrap_or(d.cjc_offset),
            enable_mask: r.array::<1>(tag::ENABLE_MASK).map(|[m]| m).unwrap_or(d.enable_mask),
        }
    }
}

/// CJC offset register encoding (manual note under Table 2-1): 0000h..AFFFh positive,
/// B000h..FFFFh negative (raw - 10000h), 0.01 °C. `None` outside ±50.00 °C.
pub fn cjc_offset_from_register(raw: u16) -> Option<i16> {
    let value = if raw <= 0xAFFF { i32::from(raw) } else { i32::from(raw) - 0x1_0000 };
    (value.abs() <= i32::from(CJC_OFFSET_LIMIT)).then_some(value as i16)
}

/// The register value of a CJC offset (two's complement, which matches the encoding above).
pub fn cjc_offset_to_register(offset: i16) -> u16 {
    offset as u16
}

remodaq_shared::impl_common_settings!(Settings);

#[cfg(test)]
mod tests {
    use super::*;

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
