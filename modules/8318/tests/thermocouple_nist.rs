//! The thermocouple functions against NIST's own data in `tests/reference/` (vendored from
//! NIST, see its README): every coefficient, every point of the 1 °C tables (forward and
//! inverse), and the acquisition cycle's cold-junction compensation against table values.

use futures_executor::block_on;
use remodaq_8318::acquisition::{acquire, AnalogFrontEnd, Measurement};
use remodaq_8318::settings::Settings;
use remodaq_8318::thermocouple::{Inverse, Reference, TcType};
use remodaq_shared::settings::Schema;

mod support {
    pub mod nist;
}

use support::nist::{nist_type, reference, table_points};

#[test]
fn coefficients_match_the_reference_file() {
    let text = reference("nist-its90-allcoeff.tab");
    let mut lines = text.lines();
    let mut tc = None;
    let mut piece = 0;
    let mut checked = 0;
    while let Some(line) = lines.next() {
        if let Some(letter) = line.strip_prefix("type: ") {
            tc = Some(nist_type(letter.trim()));
            piece = 0;
        } else if let (Some(tc), Some(range)) = (tc, line.strip_prefix("range: ")) {
            let fields: Vec<f64> = range.split(',').map(|f| f.trim().parse().unwrap()).collect();
            let ours = &tc.pieces()[piece];
            assert_eq!((ours.lo, ours.hi), (fields[0], fields[1]), "{tc:?} piece {piece} range");
            assert_eq!(ours.c.len(), fields[2] as usize + 1, "{tc:?} piece {piece} order");
            for (i, c) in ours.c.iter().enumerate() {
                let theirs: f64 = lines.next().unwrap().trim().parse().unwrap();
                assert_eq!(*c, theirs, "{tc:?} piece {piece} c{i}");
                checked += 1;
            }
            piece += 1;
        } else if line.starts_with("Inverse coefficients") {
            tc = None;
        }
    }
    assert!(checked > 150, "only {checked} coefficients compared");
}

#[test]
fn forward_matches_every_table_point() {
    let points = table_points();
    assert!(points.len() > 10_000, "parsed only {} points", points.len());
    for tc in ["B", "E", "J", "K", "N", "R", "S", "T"].map(nist_type) {
        assert!(points.iter().any(|p| p.0 == tc), "no table for {tc:?}");
    }
    for &(tc, t, mv) in &points {
        let e = tc.emf_mv(f64::from(t)).unwrap_or_else(|| panic!("{tc:?} {t} °C outside the defined range"));
        assert!((e - mv).abs() <= 0.0005 + 1e-9, "{tc:?} {t} °C: {e:.6} mV, table {mv:.3}");
    }
}

/// A cold junction outside a type's range is taken at the range's end (`emf_clamped_mv`): the
/// NIST table's first and last points, by type (R's and S's ranges end at 1768.1 °C, past
/// their tables' last whole degree: their lower ends only); a NaN stays NaN.
#[test]
fn a_cold_junction_outside_the_range_takes_the_ends_emf() {
    let points = table_points();
    for tc in ["E", "J", "K", "N", "R", "S", "T"].map(nist_type) {
        let of = points.iter().filter(|p| p.0 == tc);
        let (first, last) = (of.clone().min_by_key(|p| p.1).unwrap(), of.max_by_key(|p| p.1).unwrap());
        let ends = [(f64::from(first.1) - 40.0, first), (f64::from(last.1) + 40.0, last)];
        let ends = if matches!(tc, TcType::R | TcType::S) { &ends[..1] } else { &ends[..] };
        for &(t, end) in ends {
            let e = tc.emf_clamped_mv(t);
            assert!(
                (e - end.2).abs() <= 0.0005 + 1e-9,
                "{tc:?} at {t} °C: {e:.6} mV, table's {} °C {:.3}",
                end.1,
                end.2
            );
        }
        assert!(tc.emf_clamped_mv(f64::NAN).is_nan(), "{tc:?}");
    }
}

#[test]
fn inverse_matches_every_table_point() {
    let mut checked = 0;
    for (tc, t, mv) in table_points() {
        let t = f64::from(t);
        let (lo, _) = tc.inverse_range();
        match tc.temperature_c(mv) {
            Inverse::Celsius(back) => {
                // Exact inverse of the forward function...
                let e = tc.emf_mv(back).unwrap();
                assert!((e - mv).abs() < 1e-9, "{tc:?} {mv} mV -> {back} °C -> {e} mV");
                // ...and as close to the table's temperature as the table's 3 decimals allow.
                if t >= lo {
                    let slope = tc.emf_and_slope(t).1.min(tc.emf_and_slope(back).1);
                    let bound = 0.0005 / slope + 1e-6;
                    assert!((back - t).abs() <= bound, "{tc:?} {mv} mV: {back} °C, table {t} °C (bound {bound})");
                    checked += 1;
                }
            }
            other => {
                // Only emfs outside the function's reach: type B below its minimum, or a
                // table value at the end of the range rounded past the function's end value.
                let (lo_mv, hi_mv) = (tc.emf_and_slope(lo).0, tc.emf_mv(tc.inverse_range().1).unwrap());
                let outside = mv < lo_mv || mv > hi_mv;
                assert!(outside || (tc == TcType::B && t < lo + 20.0), "{tc:?} {t} °C ({mv} mV): {other:?}");
            }
        }
    }
    assert!(checked > 10_000);
}

/// The terminals of one channel: a fixed emf and a cold junction.
struct Terminals {
    mv: f64,
    cj: f64,
}

impl AnalogFrontEnd for Terminals {
    type Error = ();
    async fn measure(&mut self, _: u8, _: f64, _: bool) -> Result<Measurement, ()> {
        Ok(Measurement::Millivolts(self.mv))
    }
    async fn cold_junction_c(&mut self) -> Result<f64, ()> {
        Ok(self.cj)
    }
}

/// Spec §2.2: type code and engineering range of the NIST types.
const SPEC_RANGES: [(&str, u8, f64, f64); 8] = [
    ("J", 0x0E, -200.0, 1100.0),
    ("K", 0x0F, -250.0, 1400.0),
    ("T", 0x10, -250.0, 400.0),
    ("E", 0x11, -250.0, 900.0),
    ("R", 0x12, 0.0, 1750.0),
    ("S", 0x13, 0.0, 1750.0),
    ("B", 0x14, 0.0, 1800.0),
    ("N", 0x15, -250.0, 1300.0),
];

#[test]
fn cold_junction_compensation_against_the_nist_tables() {
    // A hot junction at a table temperature t and the terminals at a table temperature cj: the
    // front end sees E(t) - E(cj), both from the NIST table. The module's acquisition cycle
    // (its CJC, linearisation and scaling) must read t on the spec's range. Each table value is
    // rounded to 0.0005 mV, so the emf is known to 0.001 mV: the tolerance is that over the
    // local Seebeck coefficient (from the table), plus half a count.
    let points = table_points();
    let emf = |tc: TcType, t: i32| points.iter().find(|p| p.0 == tc && p.1 == t).map(|p| p.2);
    let mut checked = 0;
    for (letter, code, lo, hi) in SPEC_RANGES {
        let tc = nist_type(letter);
        let settings = Settings { input_type: code, enable_mask: 1, ..Settings::defaults() };
        for cj in [0, 20, 25, 45, 70] {
            let Some(e_cj) = emf(tc, cj) else { panic!("{letter}: no table value at {cj} °C") };
            for &(_, t, e_t) in points.iter().filter(|p| p.0 == tc && p.1 % 10 == 0) {
                let (tf, lo_t) = (f64::from(t), tc.inverse_range().0.max(lo));
                if tf < lo_t + 10.0 || tf > hi {
                    continue;
                }
                let (Some(below), Some(above)) = (emf(tc, t - 1), emf(tc, t + 1)) else { continue };
                let seebeck = (above - below) / 2.0;
                if seebeck < 0.002 {
                    // Type B below about 300 °C: under 2 µV/°C, the table's 3 decimals cannot
                    // tell temperatures apart to better than half a degree.
                    continue;
                }
                let mut fe = Terminals { mv: e_t - e_cj, cj: f64::from(cj) };
                let raw = block_on(acquire(&mut fe, &settings)).values[0];
                let read = lo + f64::from(raw) / 65535.0 * (hi - lo);
                let tolerance = 0.001 / seebeck + 0.5 * (hi - lo) / 65535.0;
                assert!(
                    (read - tf).abs() <= tolerance,
                    "type {letter}, {t} °C with the terminals at {cj} °C: reads {read:.4} ({raw:04X}), tolerance {tolerance:.4}"
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 5000, "{checked} points");
}

#[test]
fn out_of_range_emfs() {
    for tc in TcType::ALL {
        let (lo, hi) = tc.inverse_range();
        assert_eq!(tc.temperature_c(tc.emf_mv(hi).unwrap() + 0.01), Inverse::Above, "{tc:?}");
        assert_eq!(tc.temperature_c(tc.emf_and_slope(lo).0 - 0.01), Inverse::Below, "{tc:?}");
        assert_eq!(tc.temperature_c(f64::NAN), Inverse::Above);
    }
}

/// (type, lo, hi, coefficients) of every row of the C, L and M coefficient tables in
/// `tests/reference/README.md`.
fn readme_pieces() -> Vec<(TcType, f64, f64, Vec<f64>)> {
    let text = reference("README.md");
    let mut pieces = Vec::new();
    let mut current = None;
    for line in text.lines() {
        if line.starts_with("**C ") {
            current = Some(TcType::C);
        }
        let cells: Vec<&str> = line.split('|').map(str::trim).filter(|c| !c.is_empty()).collect();
        let [range, coefficients] = cells[..] else { continue };
        let (tc, range) = match range.split_once(", ") {
            Some(("L", r)) => (TcType::L, r),
            Some(("M", r)) => (TcType::M, r),
            _ => match current {
                Some(tc) => (tc, range),
                None => continue,
            },
        };
        let Some((lo, hi)) = range.split_once(" .. ") else { continue };
        let (Ok(lo), Ok(hi)) = (lo.parse::<f64>(), hi.parse::<f64>()) else { continue };
        let c: Vec<f64> = coefficients.split(", ").map(|v| v.parse().expect("coefficient")).collect();
        pieces.push((tc, lo, hi, c));
    }
    pieces
}

#[test]
fn c_l_m_coefficients_match_the_reference_readme() {
    let rows = readme_pieces();
    for tc in [TcType::C, TcType::L, TcType::M] {
        let ours: Vec<(f64, f64, Vec<f64>)> = tc.pieces().iter().map(|p| (p.lo, p.hi, p.c.to_vec())).collect();
        let theirs: Vec<(f64, f64, Vec<f64>)> =
            rows.iter().filter(|r| r.0 == tc).map(|r| (r.1, r.2, r.3.clone())).collect();
        assert_eq!(ours, theirs, "type {tc:?}: every subrange, every coefficient");
    }
    assert_eq!(rows.len(), 5, "C: 2 subranges, L: 2, M: 1");
}

#[test]
fn c_l_m_spot_values_in_every_subrange() {
    // Spot values of the reference README: C to 4 decimals, GOST L and M to 3; each is
    // checked forward (within half the last decimal and round-off) and inverse.
    let spots: [(TcType, f64, f64, f64); 9] = [
        (TcType::C, 1000.0, 18.2602, 0.00006),
        (TcType::L, -190.0, -9.203, 0.0006),
        (TcType::L, 200.0, 14.560, 0.0006),
        (TcType::L, 400.0, 31.492, 0.0006),
        (TcType::L, 600.0, 49.108, 0.0006),
        (TcType::L, 800.0, 66.466, 0.0006),
        (TcType::M, -150.0, -5.111, 0.0006),
        (TcType::M, -100.0, -3.715, 0.0006),
        (TcType::M, 50.0, 2.252, 0.0006),
    ];
    for (tc, t, mv, tolerance) in spots {
        let e = tc.emf_mv(t).expect("in range");
        assert!((e - mv).abs() <= tolerance, "{tc:?} {t} °C: {e} mV, reference {mv}");
        if t >= tc.defined_range().1 {
            continue; // the rounded reference emf at the top of the range may lie just above it
        }
        let Inverse::Celsius(back) = tc.temperature_c(mv) else { panic!("{tc:?} {mv} mV") };
        let slope = tc.emf_and_slope(t).1;
        assert!((back - t).abs() <= tolerance / slope + 1e-6, "{tc:?} {mv} mV: {back} °C, reference {t}");
    }
    // C's first subrange has no spot value: it starts at 0 mV at 0 °C and meets the second
    // at 630.615 °C (the two polynomials agree there to 2 µV).
    assert_eq!(TcType::C.emf_mv(0.0), Some(0.0));
    let (first, second) = (&TcType::C.pieces()[0], &TcType::C.pieces()[1]);
    let at = |c: &[f64], t: f64| c.iter().rev().fold(0.0, |acc, k| acc * t + k);
    assert!((at(first.c, 630.615) - at(second.c, 630.615)).abs() < 0.002);
}
