//! Prints, per thermocouple type, the largest deviation of the inverse from the exact inverse of
//! the forward reference function over the type's whole range, and the cost of one conversion.
//!
//! The grid runs over temperature in 0.01 °C steps: for t on the grid, E(t) is computed and
//! converted back; as the forward function is monotonic on the range, the exact inverse of
//! E(t) is t itself, so the deviation is |E^-1(E(t)) - t|. The cost is the number of forward
//! evaluations (polynomial + slope) per conversion, plus the host time per conversion.
//!
//! `cargo run --release -p firmware-8318 --example tc_accuracy`

use std::hint::black_box;
use std::time::Instant;

use remodaq_8318::thermocouple::{Inverse, Reference, TcType};

fn main() {
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
        println!(
            "{:<4} {:>9.3} {:>9.3} {:>9} {:>13.2e} {:>9.2} {:>9} {:>10.0}",
            format!("{tc:?}"),
            lo,
            hi,
            emfs.len(),
            max_dev,
            evals as f64 / emfs.len() as f64,
            max_evals,
            ns
        );
    }
    println!("largest deviation over all types: {worst:.2e} °C (requirement: 0.01 °C)");
}
