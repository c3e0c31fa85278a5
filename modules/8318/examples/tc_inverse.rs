//! Two reports on the thermocouple conversion, per type.
//!
//! 1. Consistency: how exactly the inverse undoes the module's own forward reference function.
//!    On a 0.01 °C grid over the type's range, E(t) is computed and converted back; the forward
//!    function is monotonic there, so the exact inverse of E(t) is t itself and the deviation
//!    is |E^-1(E(t)) - t|. This measures the Newton inverse, not the reference function: with
//!    a wrong coefficient it would still read near zero. Also the forward evaluations per
//!    conversion and the host time per conversion.
//! 2. Accuracy against NIST: for every point of NIST's own 1 °C tables (types B E J K N R S T,
//!    vendored in `tests/reference/`), the module's forward function against the table's emf,
//!    and the module's inverse of the table's emf against the table's temperature. The tables
//!    give emfs to 3 decimals (0.0005 mV), so the inverse cannot agree better than that over
//!    the local Seebeck coefficient: that bound is printed beside it.
//!
//! Counted checks (`tc-inverse: P passed, F failed`, exit status 1 on a failure): per type, the
//! inverse within 0.01 °C of the exact inverse; per NIST type, the forward function within the
//! tables' rounding (0.0005 mV) at every point, and the inverse of each table emf within the
//! table's own resolution at that point (0.0005 mV over the local Seebeck coefficient there).
//!
//! `cargo run --release -p remodaq-8318 --example tc_inverse`

use std::hint::black_box;
use std::time::Instant;

use remodaq_8318::thermocouple::{Inverse, Reference, TcType};

#[path = "../tests/support/nist.rs"]
mod nist;

/// Counted checks.
#[derive(Default)]
struct Checks {
    passed: u32,
    failed: u32,
}

impl Checks {
    fn check(&mut self, what: String, ok: bool) {
        if ok {
            self.passed += 1;
        } else {
            self.failed += 1;
            println!("FAILED: {what}");
        }
    }
}

/// The inverse's goal against the exact inverse (°C).
const INVERSE_GOAL_C: f64 = 0.01;

fn consistency(checks: &mut Checks) {
    println!("1. Consistency of the inverse with the module's forward function (0.01 °C grid)");
    println!(
        "{:<4} {:>9} {:>9} {:>9} {:>13} {:>9} {:>9} {:>10}",
        "type", "from °C", "to °C", "points", "max dev °C", "evals", "max", "ns/conv"
    );
    let mut worst: f64 = 0.0;
    for tc in TcType::ALL {
        let (lo, hi) = tc.inverse_range();
        let steps = ((hi - lo) / 0.01).round() as usize;
        let (mut max_dev, mut evals, mut max_evals) = (0.0f64, 0usize, 0usize);
        let mut emfs = Vec::with_capacity(steps + 1);
        for i in 0..=steps {
            let t = (lo + (hi - lo) * i as f64 / steps as f64).min(hi);
            let emf = tc.emf_mv(t).expect("in range");
            emfs.push(emf);
            let (back, n) = tc.temperature_with_iterations(emf);
            let Inverse::Celsius(back) = back else { panic!("{tc:?} {t} °C: {back:?}") };
            max_dev = max_dev.max((back - t).abs());
            evals += n;
            max_evals = max_evals.max(n);
        }
        let start = Instant::now();
        for &emf in &emfs {
            black_box(tc.temperature_c(black_box(emf)));
        }
        let ns = start.elapsed().as_nanos() as f64 / emfs.len() as f64;
        worst = worst.max(max_dev);
        checks.check(format!("{tc:?}: inverse within {INVERSE_GOAL_C} °C: {max_dev:.2e}"), max_dev <= INVERSE_GOAL_C);
        println!(
            "{:<4} {:>9.3} {:>9.3} {:>9} {:>13.2e} {:>9.2} {:>9} {:>10.0}",
            tc.letter(),
            lo,
            hi,
            emfs.len(),
            max_dev,
            evals as f64 / emfs.len() as f64,
            max_evals,
            ns
        );
    }
    println!("largest deviation from the exact inverse, all types: {worst:.2e} °C");
}

fn against_nist(checks: &mut Checks) {
    println!();
    println!("2. Accuracy against the NIST ITS-90 1 °C tables (emfs to 3 decimals)");
    println!(
        "{:<4} {:>8} {:>16} {:>16} {:>18}",
        "type", "points", "forward max mV", "inverse max °C", "table limit °C"
    );
    let points = nist::table_points();
    let mut worst_forward: f64 = 0.0;
    for letter in ["B", "E", "J", "K", "N", "R", "S", "T"] {
        let tc = nist::nist_type(letter);
        let emf = |t: i32| points.iter().find(|p| p.0 == tc && p.1 == t).map(|p| p.2);
        let (lo, hi) = tc.inverse_range();
        let (mut n, mut forward, mut inverse, mut limit) = (0, 0.0f64, 0.0f64, 0.0f64);
        // Points whose inverse lies outside that point's own table resolution.
        let mut outside = Vec::new();
        for &(_, t, mv) in points.iter().filter(|p| p.0 == tc) {
            let tf = f64::from(t);
            let (Some(below), Some(above)) = (emf(t - 1), emf(t + 1)) else { continue };
            if let Some(e) = tc.emf_mv(tf) {
                forward = forward.max((e - mv).abs());
            }
            // Where the table cannot resolve a degree (type B below about 300 °C, under
            // 2 µV/°C), only the forward agreement is meaningful.
            let seebeck = (above - below) / 2.0;
            if tf < lo || tf > hi || seebeck < 0.002 {
                continue;
            }
            if let Inverse::Celsius(back) = tc.temperature_c(mv) {
                inverse = inverse.max((back - tf).abs());
                limit = limit.max(0.0005 / seebeck);
                if (back - tf).abs() > 0.0005 / seebeck + 1e-9 {
                    outside.push(t);
                }
                n += 1;
            } else {
                outside.push(t);
            }
        }
        worst_forward = worst_forward.max(forward);
        checks.check(format!("{letter}: forward within the tables' 0.0005 mV: {forward:.5}"), forward <= 0.0005 + 1e-9);
        checks.check(
            format!("{letter}: inverse within the tables' resolution: {inverse:.4} > {limit:.4}"),
            inverse <= limit,
        );
        println!("{:<4} {:>8} {:>16.5} {:>16.4} {:>18.4}", letter, n, forward, inverse, limit);
    }
    println!("largest forward difference from the tables: {worst_forward:.5} mV (the tables round to 0.0005 mV)");
}

fn main() -> std::process::ExitCode {
    let mut checks = Checks::default();
    consistency(&mut checks);
    against_nist(&mut checks);
    println!("tc-inverse: {} passed, {} failed", checks.passed, checks.failed);
    if checks.failed == 0 {
        std::process::ExitCode::SUCCESS
    } else {
        std::process::ExitCode::FAILURE
    }
}
