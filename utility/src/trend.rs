//! The trend: the values of the channels the user picks over the last minutes, kept in memory
//! (bounded) for the plot and its CSV export.

use std::collections::{BTreeMap, VecDeque};
use std::fmt::Write as _;

/// How long a trend keeps its points, s.
pub const KEEP_S: f64 = 600.0;
/// Most points a series keeps (10 Hz for ten minutes).
pub const MAX_POINTS: usize = 6000;

/// Series by name: (seconds since the utility started, value).
#[derive(Default)]
pub struct Trend {
    pub series: BTreeMap<String, VecDeque<[f64; 2]>>,
}

impl Trend {
    /// Adds a point, dropping those older than [`KEEP_S`] and beyond [`MAX_POINTS`].
    pub fn push(&mut self, name: &str, t: f64, value: f64) {
        let s = self.series.entry(name.to_string()).or_default();
        s.push_back([t, value]);
        while s.front().is_some_and(|p| p[0] < t - KEEP_S) || s.len() > MAX_POINTS {
            s.pop_front();
        }
    }

    /// The series `names` as CSV: a time column and one column per series, one row per time
    /// any of them has a point (empty cells where a series has none); only the points within
    /// `span` (seconds, both ends included) when given.
    pub fn csv(&self, names: &[String], span: Option<(f64, f64)>) -> String {
        let mut rows: BTreeMap<u64, Vec<Option<f64>>> = BTreeMap::new();
        let within = |t: f64| span.is_none_or(|(a, b)| (a..=b).contains(&t));
        for (i, name) in names.iter().enumerate() {
            for p in self.series.get(name).into_iter().flatten().filter(|p| within(p[0])) {
                // Milliseconds as the key: points of one poll share their time.
                let row = rows.entry((p[0] * 1000.0).round() as u64).or_insert_with(|| vec![None; names.len()]);
                row[i] = Some(p[1]);
            }
        }
        let mut out = String::from("time_s");
        for n in names {
            let _ = write!(out, ",\"{}\"", header_cell(n));
        }
        out.push_str("\r\n");
        for (ms, row) in rows {
            let _ = write!(out, "{:.3}", ms as f64 / 1000.0);
            for v in row {
                out.push(',');
                if let Some(v) = v {
                    let _ = write!(out, "{v}");
                }
            }
            out.push_str("\r\n");
        }
        out
    }
}

/// A series name as a CSV header cell a spreadsheet shows as text and never runs (security
/// review finding 15): its quotes doubled (a module's name comes from its unauthenticated INFO
/// answer, so a CSV reader should not have to trust it), and a leading `=`, `+`, `-`, `@`, tab
/// or carriage return, which a spreadsheet would take for a formula, behind a `'` (OWASP's
/// advice for CSV injection).
fn header_cell(name: &str) -> String {
    let mut cell = name.replace('"', "\"\"");
    if cell.starts_with(['=', '+', '-', '@', '\t', '\r']) {
        cell.insert(0, '\'');
    }
    cell
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_name_that_looks_like_a_formula_is_exported_as_text() {
        let mut t = Trend::default();
        let evil = "=HYPERLINK(\"http://x\";\"y\") CH0 (mV)";
        t.push(evil, 1.0, 1.0);
        t.push("@SUM(A1) DI0 (count)", 1.0, 2.0);
        t.push("8318 CH1 (mV)", 1.0, 3.0);
        let csv = t.csv(&[evil.into(), "@SUM(A1) DI0 (count)".into(), "8318 CH1 (mV)".into()], None);
        let header = csv.lines().next().unwrap();
        assert_eq!(
            header,
            "time_s,\"'=HYPERLINK(\"\"http://x\"\";\"\"y\"\") CH0 (mV)\",\"'@SUM(A1) DI0 (count)\",\"8318 CH1 (mV)\""
        );
    }

    #[test]
    fn keeps_ten_minutes_and_exports_aligned_rows() {
        let mut t = Trend::default();
        for i in 0..700 {
            t.push("a", f64::from(i), f64::from(i) * 2.0);
        }
        let a = &t.series["a"];
        assert_eq!(a.front().map(|p| p[0]), Some(99.0), "older than 600 s dropped");
        let mut t = Trend::default();
        t.push("a", 1.0, 10.0);
        t.push("b", 1.0, 20.5);
        t.push("a", 2.0, 11.0);
        let csv = t.csv(&["a".into(), "b".into()], None);
        assert_eq!(csv, "time_s,\"a\",\"b\"\r\n1.000,10,20.5\r\n2.000,11,\r\n");
        let csv = t.csv(&["a".into(), "b".into()], Some((1.5, 3.0)));
        assert_eq!(csv, "time_s,\"a\",\"b\"\r\n2.000,11,\r\n", "only the span in view");
    }
}
