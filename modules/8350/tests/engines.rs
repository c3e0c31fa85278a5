//! The DI engine and the pulse engine, exercised sample by sample and tick by tick.

use remodaq_8350::di::{DiEngine, DiMode, CHANNELS};
use remodaq_8350::pulse::{DoMode, PulseConfig, PulseEngine};

const RATE: u32 = 50_000;

/// `seconds` of samples: channel n carries a 50 % square wave of `hz[n]` Hz starting low
/// (0 Hz: steady low), sampled at `RATE`.
fn square_waves(hz: &[f64; CHANNELS], seconds: f64) -> Vec<u16> {
    let n = (seconds * f64::from(RATE)).round() as u64;
    (0..n)
        .map(|i| {
            let t = i as f64 / f64::from(RATE);
            hz.iter()
                .enumerate()
                .fold(0u16, |acc, (ch, f)| if *f > 0.0 && (t * f).fract() >= 0.5 { acc | 1 << ch } else { acc })
        })
        .collect()
}

/// The rising edges in a sample stream, per channel (the oracle).
fn rising_edges(samples: &[u16]) -> [u32; CHANNELS] {
    let mut edges = [0; CHANNELS];
    for w in samples.windows(2) {
        let rising = !w[0] & w[1];
        for (ch, e) in edges.iter_mut().enumerate() {
            *e += u32::from(rising >> ch & 1);
        }
    }
    edges
}

fn engine(mode: DiMode) -> DiEngine {
    let mut e = DiEngine::new(RATE);
    for ch in 0..CHANNELS {
        e.set_mode(ch, mode);
    }
    e
}

#[test]
fn counts_square_waves_up_to_10khz_on_all_twelve_inputs() {
    let hz = [10_000.0, 10_000.0, 9_999.0, 7_777.0, 5_000.0, 3_000.0, 2_500.5, 1_000.0, 999.9, 100.0, 1.0, 10_000.0];
    let samples = square_waves(&hz, 2.0);
    let expected = rising_edges(&samples);
    // Fed in odd-sized batches, as a DMA ring hands them over.
    let mut e = engine(DiMode::Counter);
    for batch in samples.chunks(997) {
        e.process(batch);
    }
    for (ch, expected) in expected.iter().enumerate() {
        assert_eq!(e.counter_value(ch), *expected, "channel {ch}");
    }
    // And the oracle agrees with the frequencies: 2 s of a 10 kHz wave is 20 000 edges.
    assert_eq!(expected[0], 20_000);
    assert_eq!(expected[5], 6_000);
    assert_eq!(expected[10], 2);
}

#[test]
fn counts_bursts_exactly() {
    // Bursts of 1, 2, ..., 50 pulses of one sample high / one low, 100 samples apart.
    let mut samples = vec![0u16; 10];
    let mut pulses = 0;
    for burst in 1..=50 {
        for _ in 0..burst {
            samples.push(0x0FFF);
            samples.push(0);
            pulses += 1;
        }
        samples.extend(std::iter::repeat_n(0, 100));
    }
    let mut e = engine(DiMode::Counter);
    e.process(&samples);
    for ch in 0..CHANNELS {
        assert_eq!(e.counter_value(ch), pulses);
    }
}

#[test]
fn run_bit_stops_and_starts_counting() {
    let mut e = engine(DiMode::Counter);
    let wave = square_waves(&[1000.0; CHANNELS], 0.1);
    e.process(&wave);
    assert_eq!(e.counter_value(0), 100);
    e.set_run(0, false);
    e.process(&wave);
    assert_eq!(e.counter_value(0), 100, "stopped");
    assert_eq!(e.counter_value(1), 200, "others still count");
    e.set_run(0, true);
    e.process(&wave);
    assert_eq!(e.counter_value(0), 200);
    e.clear_counter(0);
    assert_eq!(e.counter_value(0), 0);
}

#[test]
fn overflow_at_2_pow_32() {
    let mut e = engine(DiMode::Counter);
    e.preset_counter(3, u32::MAX - 1);
    e.process(&[0, 0x8, 0, 0x8, 0, 0x8, 0]);
    assert_eq!(e.counter_value(3), 1);
    assert!(e.take_overflow(3));
    assert!(!e.take_overflow(3), "cleared by the read");
    // Wrapping again sets the flag again (seen without clearing it), and writing 0 clears it.
    e.preset_counter(3, u32::MAX);
    e.process(&[0x8]);
    assert_eq!(e.counter_value(3), 0, "wrapped");
    assert_eq!(e.flags().0, 1 << 3, "overflow set by the wrap, DI3 only");
    e.clear_overflow(3);
    assert_eq!(e.flags().0, 0, "cleared by writing 0");
    assert!(!e.take_overflow(3));
}

#[test]
fn latches_set_on_their_edge_only() {
    let mut e = DiEngine::new(RATE);
    e.set_mode(0, DiMode::LatchRising);
    e.set_mode(1, DiMode::LatchFalling);
    e.process(&[0b10]); // DI1 starts high: no edge on the first sample
    assert!(!e.take_latch(0) && !e.take_latch(1));
    e.process(&[0b11]); // DI0 rises
    assert!(e.take_latch(0));
    assert!(!e.take_latch(1));
    e.process(&[0b01, 0b00]); // DI1 falls, DI0 falls
    assert!(!e.take_latch(0), "falling edge does not set a rising latch");
    e.process(&[0b01]);
    e.clear_latch(0);
    assert!(!e.take_latch(0), "cleared by writing 0");
    assert!(e.take_latch(1));
}

#[test]
fn frequency_over_one_second_gates() {
    // Integer frequencies are exact: a 1 s gate holds a whole number of periods, so exactly
    // that many rising edges (1 Hz and 2 Hz included). The others are within one edge.
    let hz = [1234.5, 10_000.0, 1.0, 0.0, 3000.0, 7.25, 4999.0, 50.0, 60.0, 999.0, 2.0, 9000.0];
    let mut e = engine(DiMode::Frequency);
    let samples = square_waves(&hz, 3.0);
    let (first, rest) = samples.split_at(RATE as usize - 1);
    e.process(first);
    assert_eq!(e.counter_value(0), 0, "nothing before the first full gate");
    e.process(rest);
    for (ch, hz) in hz.iter().enumerate() {
        let got = f64::from(e.counter_value(ch));
        if hz.fract() == 0.0 {
            assert_eq!(got, *hz, "channel {ch}");
        } else {
            assert!(got == hz.floor() || got == hz.ceil(), "channel {ch}: {got} Hz for {hz} Hz");
        }
    }
}

#[test]
fn frequency_is_refreshed_once_a_second_and_follows_a_change() {
    // DI0: 5 Hz for 2 s, then 9 Hz (both start low at a whole period, so the wave is
    // continuous). The value changes exactly at each gate's last sample, never in between.
    let mut e = engine(DiMode::Frequency);
    let rate = RATE as usize;
    let mut samples = square_waves(&[5.0; CHANNELS], 2.0);
    samples.extend(square_waves(&[9.0; CHANNELS], 2.0));
    let mut published = Vec::new();
    for (i, s) in samples.iter().enumerate() {
        e.process(&[*s]);
        if (i + 1) % (rate / 2) == 0 {
            published.push((i + 1, e.counter_value(0)));
        }
    }
    // Every half second: (samples so far, value).
    let expected = [
        (rate / 2, 0),
        (rate, 5),
        (3 * rate / 2, 5),
        (2 * rate, 5),
        (5 * rate / 2, 5),
        (3 * rate, 9),
        (7 * rate / 2, 9),
        (4 * rate, 9),
    ];
    assert_eq!(published, expected);
    // One sample before a gate ends, the old value still stands.
    let mut e = engine(DiMode::Frequency);
    e.process(&samples[..3 * rate - 1]);
    assert_eq!(e.counter_value(0), 5);
    e.process(&samples[3 * rate - 1..3 * rate]);
    assert_eq!(e.counter_value(0), 9);
}

#[test]
fn mode_change_resets_the_channel() {
    let mut e = engine(DiMode::Counter);
    e.preset_counter(2, u32::MAX);
    e.process(&[0, 0x4]);
    assert_eq!(e.counter_value(2), 0);
    e.set_mode(2, DiMode::LatchRising);
    assert!(!e.take_overflow(2), "overflow cleared by the mode change");
    e.process(&[0, 0x4]);
    e.set_mode(2, DiMode::Frequency);
    assert!(!e.take_latch(2), "latch cleared by the mode change");
    e.process(&square_waves(&[100.0; CHANNELS], 1.5));
    assert_eq!(e.counter_value(2), 0, "a gate that began before the mode change is not published");
    e.set_mode(2, DiMode::Counter);
    assert_eq!(e.counter_value(2), 0);
    e.set_mode(2, DiMode::Counter);
    e.process(&[0, 0x4]);
    assert_eq!(e.counter_value(2), 1, "setting the same mode again changes nothing");
}

fn train(engine: &mut PulseEngine, n: usize, ticks: usize) -> String {
    (0..ticks).map(|_| if engine.tick() >> n & 1 == 1 { '#' } else { '.' }).collect()
}

fn pulse_engine(config: PulseConfig) -> PulseEngine {
    let mut e = PulseEngine::new();
    e.set_mode(0, DoMode::Pulse);
    e.set_config(0, config);
    e
}

#[test]
fn finite_train_tick_by_tick() {
    let mut e = pulse_engine(PulseConfig { high: 3, low: 2, count: 2 });
    assert_eq!(train(&mut e, 0, 3), "...", "off until started");
    e.set_do(0, true);
    assert!(e.do_bit(0));
    assert_eq!(train(&mut e, 0, 10), "###..###..");
    assert!(!e.do_bit(0), "the train has ended");
    assert_eq!(train(&mut e, 0, 5), ".....");
}

/// Issue #23: the outputs a command changed are written into the ticks already queued, a few
/// ticks ahead of the pin; a train must never be cut that way unless a command stops it.
#[test]
fn only_levels_and_stopped_trains_are_commanded() {
    let mut e = pulse_engine(PulseConfig { high: 3, low: 2, count: 2 });
    e.take_commanded();
    e.set_do(0, true);
    assert_eq!(e.take_commanded(), 0, "a train started begins with the next refill: nothing to rewrite");
    assert_eq!(train(&mut e, 0, 10), "###..###..");
    // The engine has computed the whole train; its last ticks may still be queued.
    e.set_do(0, false);
    assert_eq!(e.take_commanded(), 0, "a 0 written to a finished train leaves its queued ticks alone");
    e.set_do(0, true);
    assert_eq!(train(&mut e, 0, 2), "##");
    e.set_do(0, false);
    assert_eq!(e.take_commanded(), 1, "a running train stopped: rewritten from the next ticks");
    assert_eq!(e.steady(), (0b11_1111, 0), "every output holds a level, all off");
    e.set_do(1, true);
    assert_eq!(e.take_commanded(), 0b10, "a normal-mode level");
    e.set_do(0, true);
    assert_eq!(e.steady(), (0b11_1110, 0b10), "a running train is not steady");
    e.hold(0b100);
    assert_eq!(e.take_commanded(), 0b11_1111, "a hold: every output");
    assert_eq!(e.steady(), (0b11_1111, 0b100));
}

#[test]
fn five_khz_and_continuous_until_stopped() {
    let mut e = pulse_engine(PulseConfig { high: 1, low: 1, count: 0 });
    e.set_do(0, true);
    assert_eq!(train(&mut e, 0, 20_000), "#.".repeat(10_000), "5 kHz for 2 s: 10 000 pulses");
    assert!(e.do_bit(0));
    e.set_do(0, false);
    assert_eq!(train(&mut e, 0, 4), "....", "stop: output off from the next tick");
    assert!(!e.do_bit(0));
}

#[test]
fn extra_pulses_are_added_to_a_running_train() {
    let mut e = pulse_engine(PulseConfig { high: 1, low: 1, count: 100 });
    e.set_do(0, true);
    train(&mut e, 0, 50);
    e.add_pulses(0, 10);
    let rest = train(&mut e, 0, 400);
    let pulses = 25 + rest.matches('#').count();
    assert_eq!(pulses, 110, "manual note 6: 100 pulses + 10 extra = 110");
    // Extra pulses on a stopped output change nothing.
    e.add_pulses(0, 5);
    assert_eq!(train(&mut e, 0, 20), ".".repeat(20));
}

#[test]
fn width_change_applies_from_the_next_pulse() {
    let mut e = pulse_engine(PulseConfig { high: 4, low: 4, count: 0 });
    e.set_do(0, true);
    let first = train(&mut e, 0, 2);
    e.set_config(0, PulseConfig { high: 1, low: 2, count: 0 });
    let rest = train(&mut e, 0, 15);
    assert_eq!(first + &rest, "####....#..#..#..");
}

#[test]
fn normal_mode_levels_and_mode_change() {
    let mut e = PulseEngine::new();
    e.set_do(2, true);
    e.set_do(5, true);
    assert_eq!(e.tick(), 0b10_0100);
    e.set_mode(2, DoMode::Pulse);
    assert_eq!(e.tick(), 0b10_0000, "a mode change turns the output off");
    e.set_do(2, true);
    assert_eq!(e.tick() & 0b100, 0b100);
    e.set_mode(2, DoMode::Normal);
    assert!(!e.do_bit(2));
    assert_eq!(e.tick(), 0b10_0000);
}
