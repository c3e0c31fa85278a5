//! The AD7124-8 driver against a register-level fake of the chip (`support/fake_ad7124.rs`).
//! The fake's reset window here is wall-clock time; shared/clock-tests runs the reset checks
//! on a mock clock that only the driver's waits move.

use futures_executor::block_on;
use remodaq_8318::acquisition::{AnalogFrontEnd, Measurement};
use remodaq_8318::ad7124::{
    code_to_mv, gain_for_span, ntc_celsius, reg, Ad7124, Ad7124FrontEnd, Error, FrontEndError, NtcDivider,
};

#[path = "support/fake_ad7124.rs"]
mod fake;
use fake::FakeChip;

/// CONFIG bits: bipolar | REF_BUFP | REF_BUFM | AIN_BUFP | AIN_BUFM | REF_SEL = internal.
const CONFIG: u32 = 0x800 | 0x100 | 0x080 | 0x040 | 0x020 | 0b10 << 3;
/// CONFIG burnout field: 4 µA.
const BURNOUT_4UA: u32 = 0b11 << 9;

#[test]
fn init_resets_checks_id_and_configures() {
    let mut adc = Ad7124::new(FakeChip::new());
    block_on(adc.init()).unwrap();
    let chip = adc.into_inner();
    assert_eq!(chip.resets, 1);
    assert_eq!(chip.writes, vec![(reg::ADC_CONTROL, 0x0188), (reg::FILTER_0, 30), (reg::FILTER_0 + 1, 4)]);
}

#[test]
fn wrong_id_is_an_error() {
    let mut adc = Ad7124::new(FakeChip { id: 0x00, ..FakeChip::new() });
    assert_eq!(block_on(adc.init()), Err(Error::Id(0x00)));
}

#[test]
fn measures_each_pair_with_the_gain_of_its_span() {
    let mut chip = FakeChip::new();
    chip.inputs =
        [Some(41.276), Some(-12.5), Some(1200.0), Some(-2400.0), Some(0.0), Some(99.0), Some(-0.001), Some(14.9)];
    let mut adc = Ad7124::new(chip);
    block_on(async {
        adc.init().await.unwrap();
        for (pair, span, mv) in
            [(0u8, 100.0, 41.276), (1, 15.0, -12.5), (2, 2500.0, 1200.0), (3, 2500.0, -2400.0), (7, 15.0, 14.9)]
        {
            let got = adc.measure(pair, span, false).await.unwrap().unwrap();
            let lsb = 2500.0 / f64::from(1u16 << gain_for_span(span)) / 8_388_608.0;
            assert!((got - mv).abs() <= lsb, "pair {pair}: {got} mV, expected {mv}");
        }
    });
    let chip = adc.into_inner();
    // Pair 1 at ±15 mV: gain 128; CHANNEL_0 = enable | setup 0 | AIN2 | AIN3.
    assert!(chip.writes.contains(&(reg::CONFIG_0, CONFIG | 7)), "{:x?}", chip.writes);
    assert!(chip.writes.contains(&(reg::CHANNEL_0, 0x8000 | 2 << 5 | 3)));
    // The same config is not rewritten for consecutive conversions at the same gain.
    let config_writes = chip.writes.iter().filter(|w| w.0 == reg::CONFIG_0).count();
    assert_eq!(config_writes, 4, "gains 16, 128, 1, 128: {:?}", chip.writes);
}

#[test]
fn open_thermocouple_is_detected_with_burnout_currents_only_on_the_check() {
    let mut chip = FakeChip::new();
    chip.inputs[2] = None;
    chip.inputs[3] = Some(20.0);
    let mut adc = Ad7124::new(chip);
    block_on(async {
        adc.init().await.unwrap();
        assert_eq!(adc.measure(2, 100.0, true).await.unwrap(), None);
        let mv = adc.measure(3, 100.0, true).await.unwrap().unwrap();
        assert!((mv - 20.0).abs() < 1e-4);
    });
    let chip = adc.into_inner();
    // Setup 1 (open check) has the 4 µA burnout currents, setup 0 (measurement) has none.
    assert!(chip.writes.contains(&(reg::CONFIG_0 + 1, CONFIG | BURNOUT_4UA | 4)), "{:x?}", chip.writes);
    assert!(chip.writes.contains(&(reg::CONFIG_0, CONFIG | 4)));
}

#[test]
fn a_stuck_conversion_times_out() {
    let mut adc = Ad7124::new(FakeChip { stuck: true, ..FakeChip::new() });
    block_on(async {
        adc.init().await.unwrap();
        assert_eq!(adc.measure(0, 100.0, false).await, Err(Error::Timeout));
    });
}

#[test]
fn gains_and_codes() {
    assert_eq!([15.0, 50.0, 100.0, 500.0, 1000.0, 2500.0].map(gain_for_span), [7, 5, 4, 2, 1, 0]);
    assert_eq!(code_to_mv(0x80_0000, 0), 0.0);
    assert_eq!(code_to_mv(0, 0), -2500.0);
    assert_eq!(code_to_mv(0xC0_0000, 4), 2500.0 / 2.0 / 16.0);
}

#[test]
fn ntc_temperatures() {
    assert!((ntc_celsius(0.5).unwrap() - 25.0).abs() < 1e-9);
    // 10 kohm / beta 3435: R(T) = 10k exp(3435 (1/T - 1/298.15)): 28.70 kohm at 0 °C,
    // 4.101 kohm at 50 °C; the divider ratio is R / (10k + R).
    for (t, r) in [(0.0, 28_703.0), (50.0, 4_101.2)] {
        let got = ntc_celsius(r / (10_000.0 + r)).unwrap();
        assert!((got - t).abs() < 0.01, "{r} ohm: {got} °C");
    }
    assert_eq!(ntc_celsius(0.0), None);
    assert_eq!(ntc_celsius(1.0), None);
}

/// The NTC divider at a fixed ratio.
struct Ntc(f64);

impl NtcDivider for Ntc {
    fn ratio(&mut self) -> f64 {
        self.0
    }
}

#[test]
fn front_end_sets_the_chip_up_again_after_a_failure() {
    let chip = FakeChip { stuck_for: 1, inputs: [Some(10.0); 8], ..FakeChip::new() };
    let mut fe = Ad7124FrontEnd::new(chip, Ntc(0.5));
    block_on(async {
        // First conversion: set-up (reset 1), then the conversion never finishes.
        assert_eq!(fe.measure(0, 100.0, false).await, Err(FrontEndError::Adc));
        // Next: set up again (reset 2), and it converts.
        let Ok(Measurement::Millivolts(mv)) = fe.measure(0, 100.0, false).await else { panic!("no reading") };
        assert!((mv - 10.0).abs() < 1e-4, "{mv}");
        // A working chip is not reset again.
        assert!(matches!(fe.measure(1, 100.0, false).await, Ok(Measurement::Millivolts(_))));
        assert_eq!(fe.cold_junction_c().await.map(|t| (t * 1e6).round() / 1e6), Ok(25.0));
    });
    assert_eq!(fe.failures(), 1);
    let (chip, _) = fe.into_inner();
    assert_eq!(chip.resets, 2, "set up at the first conversion, and again after the failure only");
}

#[test]
fn front_end_keeps_trying_a_chip_that_does_not_answer() {
    let mut fe = Ad7124FrontEnd::new(FakeChip { id: 0x00, ..FakeChip::new() }, Ntc(0.0));
    block_on(async {
        for _ in 0..3 {
            assert_eq!(fe.measure(0, 100.0, false).await, Err(FrontEndError::Adc));
        }
        assert_eq!(fe.cold_junction_c().await, Err(FrontEndError::Ntc), "a shorted NTC");
    });
    assert_eq!(fe.failures(), 3);
    assert_eq!(fe.into_inner().0.resets, 3, "a reset before every attempt");
}

#[test]
fn configuration_waits_for_the_reset_to_complete() {
    // The fake loses writes for 2 ms after a reset, as the chip does: the filter settings
    // stick only if init waited, and init reads them back.
    let mut adc = Ad7124::new(FakeChip::new());
    block_on(adc.init()).unwrap();
    let chip = adc.into_inner();
    assert_eq!(chip.regs.get(&reg::FILTER_0), Some(&30), "FILTER_0 kept, not its reset value 060180h");
    assert_eq!(chip.regs.get(&(reg::FILTER_0 + 1)), Some(&4));
}

#[test]
fn a_register_that_does_not_keep_its_value_is_an_error() {
    let mut adc = Ad7124::new(FakeChip { deaf: Some(reg::FILTER_0), ..FakeChip::new() });
    assert_eq!(block_on(adc.init()), Err(Error::Readback(reg::FILTER_0, 30, 0x06_0180)));
}

#[test]
fn vbias_on_the_negative_inputs_for_thermocouples_only() {
    let mut chip = FakeChip::new();
    chip.inputs = [Some(1.0); 8];
    let mut adc = Ad7124::new(chip);
    block_on(async {
        adc.init().await.unwrap();
        adc.measure(0, 100.0, true).await.unwrap();
        adc.measure(1, 100.0, true).await.unwrap();
        adc.measure(0, 2500.0, false).await.unwrap();
    });
    let chip = adc.into_inner();
    let vbias: Vec<u32> = chip.writes.iter().filter(|w| w.0 == 0x04).map(|w| w.1).collect();
    assert_eq!(vbias, vec![0xAAAA, 0x0000], "AIN1, 3, ... 15 biased while thermocouples are read, once");
}

#[test]
fn conversion_timeout_from_the_filter() {
    use remodaq_8318::ad7124::{conversion_timeout, sinc4_settling_us};
    // Sinc4 single conversion: 4 / ODR, ODR = 614.4 kHz / (32 x FS).
    assert_eq!(sinc4_settling_us(30), 6_250);
    assert_eq!(sinc4_settling_us(4), 833);
    assert_eq!(conversion_timeout(30).as_micros(), 14_500);
    // FILTER_0's reset value (FS = 384) would take 80 ms: beyond the measurement's timeout,
    // which is why init must not lose its write.
    assert_eq!(sinc4_settling_us(384), 80_000);
}

/// Through the whole chain (the driver's gain choice, the chip's 24-bit conversion as the fake
/// models it, code to mV, scaling), a voltage or current across each range of spec §2.2 reads
/// the spec's mapping round((x - lo) / (hi - lo) * 65535) to within one output code. The fake
/// chip is ideal (its 2.500 V reference exact, no noise, no offset or gain error), and its
/// 24-bit quantization is over 100 times finer than one output code at every gain, so the
/// only error left is the rounding to the output code: one code. The ±0.1 % of span of spec
/// §2.5 (about 65 codes) is the hardware's budget (reference tolerance, noise, offset and gain
/// errors of a real AD7124 and its front end), not a tolerance of this arithmetic: a reference
/// of 2.501 V in `code_to_mv` (0.04 %, about 26 codes at full scale) is a wrong module here.
/// Ranges are the spec's.
#[test]
fn voltage_and_current_ranges_read_the_specs_mapping_within_one_code() {
    use remodaq_8318::acquisition::acquire;
    // The current input's shunt (docs/register-map-8318.md: ±20 mA through 100 ohm).
    const SHUNT_OHMS: f64 = 100.0;
    use remodaq_8318::settings::Settings;
    use remodaq_shared::settings::Schema;
    // Code, range (mV, or mA for 06), and the mV per unit at the terminals.
    let ranges = [
        (0x00u8, -15.0, 15.0, 1.0),
        (0x01, -50.0, 50.0, 1.0),
        (0x02, -100.0, 100.0, 1.0),
        (0x03, -500.0, 500.0, 1.0),
        (0x04, -1000.0, 1000.0, 1.0),
        (0x05, -2500.0, 2500.0, 1.0),
        (0x06, -20.0, 20.0, SHUNT_OHMS),
    ];
    for (code, lo, hi, mv_per_unit) in ranges {
        let points: [f64; 8] = [-1.0, -0.999, -0.5, -0.1234, 0.0, 0.37, 0.9, 0.999].map(|f| f * hi);
        let mut chip = FakeChip::new();
        for (input, x) in chip.inputs.iter_mut().zip(points) {
            *input = Some(x * mv_per_unit);
        }
        let mut fe = Ad7124FrontEnd::new(chip, Ntc(0.5));
        let settings = Settings { input_type: code, ..Settings::defaults() };
        let snapshot = block_on(acquire(&mut fe, &settings));
        for (n, x) in points.iter().enumerate() {
            let ideal = ((x - lo) / (hi - lo) * 65535.0).round();
            let got = f64::from(snapshot.values[n]);
            assert!((got - ideal).abs() <= 1.0, "code {code:02X}, {x}: read {got}, the spec's mapping {ideal}");
        }
    }
}
