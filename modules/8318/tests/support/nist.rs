//! The NIST ITS-90 data vendored in `tests/reference/`: read by the NIST tests and by the
//! `tc_inverse` example (`#[path]`-included there).
#![allow(dead_code)]

use remodaq_8318::thermocouple::TcType;

/// Where the vendored reference files are.
pub const REFERENCE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/reference/");

/// The text of reference file `file`.
pub fn reference(file: &str) -> String {
    std::fs::read_to_string(format!("{REFERENCE}{file}")).unwrap_or_else(|e| panic!("{REFERENCE}{file}: {e}"))
}

/// The type of a NIST table's letter.
pub fn nist_type(letter: &str) -> TcType {
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
pub fn table_points() -> Vec<(TcType, i32, f64)> {
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
