//! The thermocouple functions against NIST's own data in `tests/reference/` (vendored from NIST, see its README): every
//! coefficient, every point of the 1 °C tables (forward and inverse), and cold-junction
//! compensation round trips.

use remodaq_8318::thermocouple::{Inverse, Reference, TcType};

const REFERENCE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/reference/");

fn reference(file: &str) -> String {
    std::fs::read_to_string(format!("{REFERENCE}{file}")).unwrap_or_else(|e| panic!("{REFERENCE}{file}: {e}"))
}

fn nist_type(letter: &str) -> TcType {
    match letter {
        "B" => TcType::B,
        "E" => TcType::E,
        "J" => TcType::J,
        "K" => TcType::K,
        "N" => TcType::N,
        "R" => TcType::R,
        "S" => TcType::S,
        "T" => TcType::T,
        other => panic!("unexpected type {other}"),
    }
}

/// (type, °C, mV) for every entry of the NIST 1 °C tables.
fn table_points() -> Vec<(TcType, i32, f64)> {
    let text = reference("nist-its90-tables.tab");
    let mut points = Vec::new();
    let mut tc = None;
    let mut direction = 1;
    for line in text.lines() {
        if let Some(rest) = line.split("ITS-90 Table for type ").nth(1) {
            tc = Some(nist_type(&rest[..1]));
            continue;
        }
        let tokens: Vec<&str> = line.split_whitespace().collect();
        if tokens.first() == Some(&"°C") {
            direction = if tokens.get(2) == Some(&"-1") { -1 } else { 1 };
            continue;
        }
        let (Some(tc), Some(Ok(base))) = (tc, tokens.first().map(|t| t.parse::<i32>())) else { continue };
        let values: Vec<f64> = tokens[1..].iter().map_while(|v| v.parse().ok()).collect();
        if values.is_empty() || values.len() != tokens.len() - 1 {
            continue;
        }
        for (j, mv) in values.into_iter().enumerate() {
            points.push((tc, base + direction * j as i32, mv));
        }
    }
    points
}

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

#[test]
fn cold_junction_compensation_round_trips() {
    // A hot junction at t, a cold junction at cj: the terminals see E(t) - E(cj); adding E(cj)
    // back and inverting must give t again, for every type over its range.
    for tc in TcType::ALL {
        let (lo, hi) = tc.inverse_range();
        for cj in [-20.0, 0.0, 23.5, 45.0, 70.0] {
            let steps = 97;
            for i in 0..=steps {
                let t = lo + (hi - lo) * f64::from(i) / f64::from(steps);
                let measured = tc.emf_mv(t).unwrap() - tc.emf_clamped_mv(cj);
                let total = measured + tc.emf_clamped_mv(cj);
                match tc.temperature_c(total) {
                    Inverse::Celsius(back) => assert!((back - t).abs() < 0.001, "{tc:?} t {t} cj {cj}: {back}"),
                    other => panic!("{tc:?} t {t} cj {cj}: {other:?}"),
                }
            }
        }
    }
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
