//! Every input code of spec §2.2 against the spec's own numbers: the engineering range of the
//! table, and the §2.3 mapping raw = round((x - lo) / (hi - lo) * 65535) at the ends, the
//! middle and beyond the range, through the acquisition cycle (for voltages and the current)
//! and the type table (for thermocouples; their linearisation is checked against the NIST
//! tables in `thermocouple_nist.rs`). Expected values are literals taken from the spec.

use futures_executor::block_on;
use remodaq_8318::acquisition::{acquire, AnalogFrontEnd, Measurement};
use remodaq_8318::input::InputType;
use remodaq_8318::settings::Settings;
use remodaq_shared::settings::Schema;

/// Spec §2.2, as printed: code, engineering range (mV, mA or °C).
const SPEC: [(u8, f64, f64); 18] = [
    (0x00, -15.0, 15.0),
    (0x01, -50.0, 50.0),
    (0x02, -100.0, 100.0),
    (0x03, -500.0, 500.0),
    (0x04, -1000.0, 1000.0),
    (0x05, -2500.0, 2500.0),
    (0x06, -20.0, 20.0),
    (0x0E, -200.0, 1100.0),
    (0x0F, -250.0, 1400.0),
    (0x10, -250.0, 400.0),
    (0x11, -250.0, 900.0),
    (0x12, 0.0, 1750.0),
    (0x13, 0.0, 1750.0),
    (0x14, 0.0, 1800.0),
    (0x15, -250.0, 1300.0),
    (0x16, 0.0, 2310.0),
    (0x17, -200.0, 800.0),
    (0x18, -200.0, 100.0),
];

/// All eight channels at one voltage.
struct Terminals(f64);

impl AnalogFrontEnd for Terminals {
    type Error = ();
    async fn measure(&mut self, _: u8, _: f64, _: bool) -> Result<Measurement, ()> {
        Ok(Measurement::Millivolts(self.0))
    }
    async fn cold_junction_c(&mut self) -> Result<f64, ()> {
        Ok(25.0)
    }
}

/// Channel 0's register for `mv` at the terminals with input type `code`.
fn register(code: u8, mv: f64) -> u16 {
    let settings = Settings { input_type: code, ..Settings::defaults() };
    block_on(acquire(&mut Terminals(mv), &settings)).values[0]
}

#[test]
fn every_code_has_the_range_of_the_spec_table() {
    for (code, lo, hi) in SPEC {
        let t = InputType::from_code(code).unwrap_or_else(|| panic!("code {code:02X} missing"));
        assert_eq!((t.lo, t.hi), (lo, hi), "code {code:02X}");
    }
    for code in (0..=0xFFu8).filter(|c| !SPEC.iter().any(|s| s.0 == *c)) {
        assert!(InputType::from_code(code).is_none(), "code {code:02X} is not in the spec");
    }
}

#[test]
fn voltage_and_current_codes_scale_as_the_spec_says() {
    // (code, mV at the terminals per engineering unit): the current flows through the 100 ohm
    // shunt, so 1 mA is 100 mV.
    for (code, lo, hi) in SPEC.iter().copied().filter(|s| s.0 <= 0x06) {
        let per_unit = if code == 0x06 { 100.0 } else { 1.0 };
        let span = hi - lo;
        let cases = [
            (lo, 0x0000),
            (hi, 0xFFFF),
            // The middle: 32767.5 rounds to 32768.
            ((lo + hi) / 2.0, 0x8000),
            // A quarter: 16383.75.
            (lo + span / 4.0, 16384),
            // Three quarters: 49151.25.
            (lo + span * 0.75, 49151),
            // Beyond the range: clamped.
            (lo - span / 10.0, 0x0000),
            (hi + span / 10.0, 0xFFFF),
        ];
        for (x, want) in cases {
            assert_eq!(register(code, x * per_unit), want, "code {code:02X} at {x}");
        }
    }
}

#[test]
fn thermocouple_codes_scale_as_the_spec_says() {
    for (code, lo, hi) in SPEC.iter().copied().filter(|s| s.0 >= 0x0E) {
        let t = InputType::from_code(code).expect("code");
        assert_eq!(t.raw(lo), 0x0000, "code {code:02X}");
        assert_eq!(t.raw(hi), 0xFFFF, "code {code:02X}");
        assert_eq!(t.raw((lo + hi) / 2.0), 0x8000, "code {code:02X}");
        assert_eq!(t.raw(lo + (hi - lo) * 0.75), 49151, "code {code:02X}");
        assert_eq!(t.raw(lo - 1.0), 0x0000, "code {code:02X}");
        assert_eq!(t.raw(hi + 1.0), 0xFFFF, "code {code:02X}");
    }
}
