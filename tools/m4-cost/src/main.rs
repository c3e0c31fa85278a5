//! Cost on a Cortex-M4F of one thermocouple conversion (8318: emf -> °C, f64) and of the 8350's
//! engines (per input sample, per output tick), measured in QEMU
//! (netduinoplus2: an STM32F405, Cortex-M4F, with the STM32F429's memory layout) with
//! `-icount shift=0`: virtual time then advances 1 ns per instruction and SysTick (core clock)
//! follows it, so a run's tick count is proportional to the instructions it executed; a
//! calibration loop of known length gives the ratio on every run.
//!
//! Run: `tools/m4-cost/run` (builds for thumbv7em-none-eabihf and starts QEMU).
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("m4-cost runs on the target: use tools/m4-cost/run");
}

#[cfg(target_os = "none")]
mod target {
    use core::hint::black_box;

    use core::sync::atomic::{AtomicU32, Ordering};
    use cortex_m::peripheral::syst::SystClkSource;
    use cortex_m_rt::entry;
    use cortex_m_semihosting::{debug, hprintln};
    use remodaq_8318::thermocouple::{Reference, TcType};

    const POINTS: u32 = 64;

    fn now() -> u32 {
        // SysTick counts down from its reload value.
        0x00FF_FFFF - cortex_m::peripheral::SYST::get_current()
    }

    /// SysTick ticks taken by `f` (less than 2^24, i.e. 0.67 s of virtual time).
    fn ticks(f: impl FnOnce()) -> u32 {
        let start = now();
        f();
        now().wrapping_sub(start) & 0x00FF_FFFF
    }

    #[panic_handler]
    fn panic(_: &core::panic::PanicInfo) -> ! {
        debug::exit(debug::EXIT_FAILURE);
        loop {
            cortex_m::asm::wfi();
        }
    }

    /// Counted goals (`m4-cost: P passed, F failed`), at one cycle per instruction on a
    /// 180 MHz M4 (docs/design.md): what runs under a critical section fits 20 µs.
    static PASSED: AtomicU32 = AtomicU32::new(0);
    static FAILED: AtomicU32 = AtomicU32::new(0);
    fn goal(what: &str, value: f64, max: f64) {
        let ok = value <= max;
        hprintln!("m4-cost goal: {}: {:.0} <= {:.0} ... {}", what, value, max, if ok { "ok" } else { "FAILED" });
        if ok { &PASSED } else { &FAILED }.fetch_add(1, Ordering::Relaxed);
    }
    /// Instructions in 20 µs at 180 MHz, one a cycle.
    const LOCKED_BUDGET: f64 = 20e-6 * 180e6;

    /// The 8350's DI engine per sample (12 inputs) and pulse engine per tick (6 outputs).
    fn engines(per_tick: f64) {
        use remodaq_8350::di::{DiEngine, DiMode, CHANNELS, SAMPLE_RATE_HZ};
        use remodaq_8350::pulse::{DoMode, PulseConfig, PulseEngine};

        const N: usize = 5000;
        static mut SAMPLES: [u16; N] = [0; N];
        // SAFETY: single-threaded bare-metal program; the only reference to the buffer.
        let samples = unsafe { &mut *core::ptr::addr_of_mut!(SAMPLES) };
        let mut engine = DiEngine::new(SAMPLE_RATE_HZ);
        for ch in 0..CHANNELS {
            engine.set_mode(ch, if ch % 2 == 0 { DiMode::Counter } else { DiMode::Frequency });
        }
        let mut run = |label: &str, samples: &[u16]| {
            let t = ticks(|| engine.process(black_box(samples)));
            let edges: u32 = samples.windows(2).map(|w| (!w[0] & w[1]).count_ones()).sum();
            let instr = f64::from(t) * per_tick;
            let per_sample = instr / samples.len() as f64;
            if edges == 0 {
                hprintln!("{:<50} {:>6.1} instr/sample", label, per_sample);
            } else {
                let per_edge = instr / f64::from(edges);
                hprintln!("{:<50} {:>6.1} instr/sample {:>6.1} instr/rising edge", label, per_sample, per_edge);
            }
            instr / samples.len() as f64
        };
        // Twelve 10 kHz square waves at 50 kHz sampling, phases spread over the period.
        for (i, s) in samples.iter_mut().enumerate() {
            *s = (0..CHANNELS).fold(0, |acc, ch| if (i + ch) % 5 < 2 { acc | 1 << ch } else { acc });
        }
        let busy = run("DI: 12 inputs at 10 kHz (12 edges per 5 samples)", samples);
        goal(
            "DI: instructions of the samples processed under one lock (LOCKED_SAMPLES), 20 µs",
            busy * remodaq_8350::io::LOCKED_SAMPLES as f64,
            LOCKED_BUDGET,
        );
        samples.fill(0x0A5A);
        run("DI: steady inputs (no edges)", samples);
        hprintln!(
            "DI at 50 kHz with 12 x 10 kHz: {:.1} % of a 180 MHz M4 at one cycle per instruction",
            busy * f64::from(SAMPLE_RATE_HZ) / 180e6 * 100.0
        );
        let mut pulses = PulseEngine::new();
        for n in 0..6 {
            pulses.set_mode(n, DoMode::Pulse);
            pulses.set_config(n, PulseConfig { high: 1, low: 1, count: 0 });
            pulses.set_do(n, true);
        }
        let mut pattern = [0u8; 1000];
        let t = ticks(|| pulses.fill(black_box(&mut pattern)));
        let per_output_tick = f64::from(t) * per_tick / 1000.0;
        hprintln!("pulse: 6 outputs at 5 kHz: {:.1} instr/tick (10 000 ticks/s)", per_output_tick);
        goal(
            "pulse: instructions of the ticks filled under one lock (LOCKED_TICKS), 20 µs",
            per_output_tick * remodaq_8350::io::LOCKED_TICKS as f64,
            LOCKED_BUDGET,
        );
    }

    #[entry]
    fn main() -> ! {
        let Some(mut p) = cortex_m::Peripherals::take() else { panic!() };
        p.SYST.set_clock_source(SystClkSource::Core);
        p.SYST.set_reload(0x00FF_FFFF);
        p.SYST.clear_current();
        p.SYST.enable_counter();

        // Calibration: 100 000 iterations of a 2-instruction loop = 200 000 instructions.
        let cal = ticks(|| unsafe {
            // SAFETY: a register-only countdown loop; touches no memory.
            core::arch::asm!("1: subs {0}, {0}, #1", "bne 1b", inout(reg) 100_000u32 => _);
        });
        let per_tick = 200_000.0 / f64::from(cal.max(1));
        hprintln!("calibration: 200000 instructions = {} ticks ({:.1} instructions per tick)", cal, per_tick);
        hprintln!("{:<5} {:>14} {:>14} {:>12}", "type", "instr/conv", "forward evals", "µs @180MHz*");
        for tc in TcType::ALL {
            let (lo, hi) = tc.inverse_range();
            let (elo, ehi) = (tc.emf_clamped_mv(lo), tc.emf_clamped_mv(hi));
            // The emfs are computed before the timed region (soft-float arithmetic of the
            // harness, not of a conversion); inside it only the conversions and a sum run.
            let mut emfs = [0.0f64; POINTS as usize];
            for (i, emf) in emfs.iter_mut().enumerate() {
                *emf = elo + (ehi - elo) * (i as f64 + 0.5) / f64::from(POINTS);
            }
            let mut evals = 0usize;
            let t = ticks(|| {
                for emf in &emfs {
                    evals += black_box(tc.temperature_with_iterations(black_box(*emf))).1;
                }
            });
            let instr = f64::from(t) * per_tick / f64::from(POINTS);
            // 8 channels a 100 ms cycle: a conversion within 1 ms (180 000 instructions) keeps
            // them under a tenth of the cycle.
            goal("thermocouple conversion (one a channel), instructions", instr, 180_000.0);
            hprintln!(
                "{:<5} {:>14.0} {:>14.2} {:>12.1}",
                tc.letter(),
                instr,
                evals as f64 / f64::from(POINTS),
                instr / 180.0
            );
        }
        hprintln!("* at one cycle per instruction: a lower bound; flash wait states and soft-float add some.");
        engines(per_tick);
        let (passed, failed) = (PASSED.load(Ordering::Relaxed), FAILED.load(Ordering::Relaxed));
        hprintln!("m4-cost: {} passed, {} failed", passed, failed);
        debug::exit(if failed == 0 { debug::EXIT_SUCCESS } else { debug::EXIT_FAILURE });
        loop {
            cortex_m::asm::wfi();
        }
    }
}
