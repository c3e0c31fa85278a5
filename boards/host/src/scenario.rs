//! Scenario files (spec host-build.md): the signals at the simulated module's terminals, in
//! TOML, re-read when the file changes. A missing or malformed file at start is a clear error
//! naming the line; a change that breaks the file later is logged (with its line) and the
//! previous scenario stays in force until the file is fixed.

use std::path::{Path, PathBuf};
use std::time::SystemTime;

use serde::Deserialize;
use toml::Spanned;

/// A scenario file and its last good content.
pub struct Watched<T> {
    path: PathBuf,
    modified: Option<SystemTime>,
    current: T,
    parse: fn(&str) -> Result<T, String>,
}

impl<T> Watched<T> {
    /// Reads and parses `path`; the error names the file and the line.
    pub fn load(path: &Path, parse: fn(&str) -> Result<T, String>) -> Result<Self, String> {
        let modified = modified(path);
        let text = std::fs::read_to_string(path).map_err(|e| format!("scenario {}: {e}", path.display()))?;
        let current = parse(&text).map_err(|e| format!("scenario {}: {e}", path.display()))?;
        Ok(Self { path: path.to_path_buf(), modified, current, parse })
    }

    /// The scenario in force, re-read first if the file changed since the last read.
    pub fn refresh(&mut self) -> &T {
        let modified = modified(&self.path);
        if modified != self.modified {
            self.modified = modified;
            match std::fs::read_to_string(&self.path).map_err(|e| e.to_string()).and_then(|t| (self.parse)(&t)) {
                Ok(new) => {
                    self.current = new;
                    log::info!("scenario {}: reloaded", self.path.display());
                }
                Err(e) => log::error!("scenario {}: {e}; keeping the previous scenario", self.path.display()),
            }
        }
        &self.current
    }
}

fn modified(path: &Path) -> Option<SystemTime> {
    std::fs::metadata(path).and_then(|m| m.modified()).ok()
}

/// 1-based line of byte `offset` in `text`.
fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

fn toml_error(e: toml::de::Error, text: &str) -> String {
    match e.span() {
        Some(span) => format!("line {}: {}", line_of(text, span.start), e.message()),
        None => e.message().to_string(),
    }
}

/// What is connected to an analog input's terminals (8318).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Terminal {
    /// A voltage or thermocouple emf, mV.
    Millivolts(f64),
    /// A voltage, V.
    Volts(f64),
    /// A current through the input's shunt, mA.
    Milliamps(f64),
    /// Nothing: an open input (a burnt-out thermocouple).
    Open,
}

/// The 8318's terminals.
#[derive(Clone, Debug, PartialEq)]
pub struct Analog {
    /// Cold-junction (terminal block) temperature, °C.
    pub cjc_celsius: f64,
    /// Channels 0-7.
    pub channels: [Terminal; 8],
    /// `[cjc] fault = true`: the cold-junction sensor cannot be read.
    pub cjc_fault: bool,
    /// `[frontend] fault = true`: the ADC does not answer (every conversion fails).
    pub frontend_fault: bool,
}

impl Default for Analog {
    /// Without a scenario: 25 °C terminals, 0 mV on every channel.
    fn default() -> Self {
        Self { cjc_celsius: 25.0, channels: [Terminal::Millivolts(0.0); 8], cjc_fault: false, frontend_fault: false }
    }
}

/// `[cjc]` or `[frontend]`: an injected fault.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFault {
    fault: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawAnalog {
    cjc_celsius: Option<f64>,
    cjc: Option<RawFault>,
    frontend: Option<RawFault>,
    ch0: Option<Spanned<RawChannel>>,
    ch1: Option<Spanned<RawChannel>>,
    ch2: Option<Spanned<RawChannel>>,
    ch3: Option<Spanned<RawChannel>>,
    ch4: Option<Spanned<RawChannel>>,
    ch5: Option<Spanned<RawChannel>>,
    ch6: Option<Spanned<RawChannel>>,
    ch7: Option<Spanned<RawChannel>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawChannel {
    millivolts: Option<f64>,
    volts: Option<f64>,
    milliamps: Option<f64>,
    open: Option<bool>,
}

/// Parses an 8318 scenario.
pub fn parse_analog(text: &str) -> Result<Analog, String> {
    let raw: RawAnalog = toml::from_str(text).map_err(|e| toml_error(e, text))?;
    let mut analog = Analog {
        cjc_celsius: raw.cjc_celsius.unwrap_or(25.0),
        cjc_fault: raw.cjc.is_some_and(|f| f.fault),
        frontend_fault: raw.frontend.is_some_and(|f| f.fault),
        ..Analog::default()
    };
    if !analog.cjc_celsius.is_finite() {
        return Err("cjc_celsius must be a finite number".into());
    }
    let channels = [raw.ch0, raw.ch1, raw.ch2, raw.ch3, raw.ch4, raw.ch5, raw.ch6, raw.ch7];
    for (n, channel) in channels.into_iter().enumerate() {
        let Some(channel) = channel else { continue };
        let line = line_of(text, channel.span().start);
        let c = channel.into_inner();
        let given = [
            c.millivolts.map(Terminal::Millivolts),
            c.volts.map(Terminal::Volts),
            c.milliamps.map(Terminal::Milliamps),
        ];
        let mut terminals: Vec<Terminal> = given.into_iter().flatten().collect();
        match c.open {
            Some(true) => terminals.push(Terminal::Open),
            Some(false) if terminals.is_empty() => terminals.push(Terminal::Millivolts(0.0)),
            _ => {}
        }
        match terminals.as_slice() {
            [t] if !matches!(t, Terminal::Millivolts(v) | Terminal::Volts(v) | Terminal::Milliamps(v) if !v.is_finite()) => {
                analog.channels[n] = *t
            }
            [_] => return Err(format!("line {line}: [ch{n}] value must be a finite number")),
            _ => {
                return Err(format!(
                    "line {line}: [ch{n}] needs exactly one of millivolts, volts, milliamps, open = true"
                ))
            }
        }
    }
    Ok(analog)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spec_example() {
        let text = "cjc_celsius = 25.0\n\n[ch0]\nmillivolts = 41.276\n[ch1]\nvolts = 1.2\n[ch2]\nmilliamps = 12.0\n[ch3]\nopen = true\n";
        let a = parse_analog(text).unwrap();
        assert_eq!(a.cjc_celsius, 25.0);
        assert_eq!(
            a.channels[..5],
            [
                Terminal::Millivolts(41.276),
                Terminal::Volts(1.2),
                Terminal::Milliamps(12.0),
                Terminal::Open,
                Terminal::Millivolts(0.0)
            ]
        );
        assert_eq!(parse_analog("").unwrap(), Analog::default());
    }

    #[test]
    fn errors_name_the_line() {
        let e = parse_analog("cjc_celsius = 20\n[ch0]\nmillivolts = 1\nvolts = 2\n").unwrap_err();
        assert!(e.starts_with("line 2:") && e.contains("exactly one"), "{e}");
        let e = parse_analog("[ch1]\nmillivolts = 1\n\n[ch9]\nvolts = 1\n").unwrap_err();
        assert!(e.starts_with("line 4:"), "{e}");
        let e = parse_analog("[ch0]\nmilivolts = 1\n").unwrap_err();
        assert!(e.starts_with("line 2:"), "{e}");
        let e = parse_analog("[ch0]\nmillivolts = \"a\"\n").unwrap_err();
        assert!(e.starts_with("line 2:"), "{e}");
        let e = parse_analog("cjc_celsius = 20\nnot toml at all\n").unwrap_err();
        assert!(e.starts_with("line 2:"), "{e}");
        let e = parse_analog("[ch0]\nmillivolts = nan\n").unwrap_err();
        assert!(e.contains("finite"), "{e}");
    }

    #[test]
    fn a_broken_change_keeps_the_previous_scenario() {
        let dir = std::env::temp_dir().join(format!("remodaq-scenario-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("s.toml");
        std::fs::write(&path, "[ch0]\nvolts = 1.0\n").unwrap();
        let mut w = Watched::load(&path, parse_analog).unwrap();
        assert_eq!(w.refresh().channels[0], Terminal::Volts(1.0));
        std::thread::sleep(std::time::Duration::from_millis(20));
        std::fs::write(&path, "[ch0]\nvolts = \n").unwrap();
        assert_eq!(w.refresh().channels[0], Terminal::Volts(1.0));
        std::thread::sleep(std::time::Duration::from_millis(20));
        std::fs::write(&path, "[ch0]\nvolts = 2.0\n").unwrap();
        assert_eq!(w.refresh().channels[0], Terminal::Volts(2.0));
        assert!(Watched::load(&dir.join("missing.toml"), parse_analog).err().unwrap().contains("missing.toml"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

/// What drives a digital input (8350).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Signal {
    /// A steady level.
    Level(bool),
    /// A 50 % duty square wave of this frequency (Hz), starting low.
    Square(f64),
    /// Wired to output DOn of the module itself (`from_do = n`): the board samples the level
    /// that output plays.
    FromDo(u8),
}

impl Signal {
    /// The level at `t` seconds.
    pub fn level_at(&self, t: f64) -> bool {
        match *self {
            Signal::Level(level) => level,
            Signal::Square(hz) => (t * hz).fract() >= 0.5,
            // The board overlays the output's level (boards/host/src/digital.rs).
            Signal::FromDo(_) => false,
        }
    }
}

/// The 8350's inputs.
#[derive(Clone, Debug, PartialEq)]
pub struct Digital {
    /// DI0-DI11.
    pub inputs: [Signal; 12],
    /// `[capture] lose_samples = true`: the capture loses samples (its ring overruns) while
    /// set.
    pub lose_samples: bool,
}

impl Default for Digital {
    /// Without a scenario: every input steady low.
    fn default() -> Self {
        Self { inputs: [Signal::Level(false); 12], lose_samples: false }
    }
}

impl Digital {
    /// The port snapshot (bit n = DIn) at `t` seconds.
    pub fn sample_at(&self, t: f64) -> u16 {
        self.inputs.iter().enumerate().fold(0, |acc, (n, s)| if s.level_at(t) { acc | 1 << n } else { acc })
    }
}

/// A `[diN]` table, or `[capture]` (`lose_samples`).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawInput {
    square_hz: Option<f64>,
    level: Option<bool>,
    from_do: Option<u8>,
    lose_samples: Option<bool>,
}

/// Parses an 8350 scenario: `[diN]` tables with exactly one of `square_hz`, `level` or
/// `from_do` (0-5: the input wired to that output), and
/// `[capture] lose_samples = true|false`.
pub fn parse_digital(text: &str) -> Result<Digital, String> {
    let raw: std::collections::BTreeMap<String, Spanned<RawInput>> =
        toml::from_str(text).map_err(|e| toml_error(e, text))?;
    let mut digital = Digital::default();
    for (key, input) in raw {
        let line = line_of(text, input.span().start);
        let input = input.into_inner();
        if key == "capture" {
            match (input.lose_samples, input.square_hz, input.level, input.from_do) {
                (Some(lose), None, None, None) => digital.lose_samples = lose,
                _ => return Err(format!("line {line}: [capture] takes lose_samples = true|false only")),
            }
            continue;
        }
        if input.lose_samples.is_some() {
            return Err(format!("line {line}: lose_samples belongs in [capture]"));
        }
        let n: usize = key
            .strip_prefix("di")
            .and_then(|n| n.parse().ok())
            .filter(|n| *n < 12)
            .ok_or_else(|| format!("line {line}: unknown table [{key}]; inputs are [di0] to [di11]"))?;
        digital.inputs[n] = match (input.square_hz, input.level, input.from_do) {
            (Some(hz), None, None) if hz.is_finite() && hz > 0.0 && hz <= 25_000.0 => Signal::Square(hz),
            (Some(_), None, None) => return Err(format!("line {line}: [di{n}] square_hz must be in 0 < f <= 25000")),
            (None, Some(level), None) => Signal::Level(level),
            (None, None, Some(m)) if m < 6 => Signal::FromDo(m),
            (None, None, Some(_)) => return Err(format!("line {line}: [di{n}] from_do must be an output, 0 to 5")),
            _ => return Err(format!("line {line}: [di{n}] needs exactly one of square_hz, level, from_do")),
        };
    }
    Ok(digital)
}

#[cfg(test)]
mod digital_tests {
    use super::*;

    #[test]
    fn the_spec_example_and_errors() {
        let d = parse_digital("[di0]\nsquare_hz = 1000.0\n[di1]\nlevel = true\n").unwrap();
        assert_eq!(d.inputs[0], Signal::Square(1000.0));
        assert_eq!(d.inputs[1], Signal::Level(true));
        assert_eq!(d.inputs[2], Signal::Level(false));
        assert_eq!(d.sample_at(0.0), 0b10);
        assert_eq!(d.sample_at(0.0006), 0b11);
        let e = parse_digital("[di0]\nlevel = true\n\n[di12]\nlevel = true\n").unwrap_err();
        assert!(e.starts_with("line 4:"), "{e}");
        let e = parse_digital("[di3]\nlevel = true\nsquare_hz = 5.0\n").unwrap_err();
        assert!(e.starts_with("line 1:") && e.contains("exactly one"), "{e}");
        let d = parse_digital("[di1]\nfrom_do = 0\n").unwrap();
        assert_eq!(d.inputs[1], Signal::FromDo(0));
        let e = parse_digital("[di1]\nfrom_do = 6\n").unwrap_err();
        assert!(e.starts_with("line 1:") && e.contains("from_do"), "{e}");
        let e = parse_digital("[di3]\nsquare_hz = -5.0\n").unwrap_err();
        assert!(e.contains("square_hz"), "{e}");
        let e = parse_digital("[di3]\nlevle = true\n").unwrap_err();
        assert!(e.starts_with("line 2:"), "{e}");
    }
}

#[cfg(test)]
mod fault_tests {
    use super::*;

    #[test]
    fn injected_faults() {
        let a = parse_analog("[frontend]\nfault = true\n[cjc]\nfault = false\n").unwrap();
        assert!(a.frontend_fault && !a.cjc_fault);
        assert!(parse_analog("[cjc]\nfault = 1\n").is_err());
        let d = parse_digital("[capture]\nlose_samples = true\n[di0]\nlevel = true\n").unwrap();
        assert!(d.lose_samples);
        let e = parse_digital("[di0]\nlose_samples = true\n").unwrap_err();
        assert!(e.contains("[capture]"), "{e}");
        let e = parse_digital("[capture]\nlevel = true\n").unwrap_err();
        assert!(e.starts_with("line 1:"), "{e}");
    }
}
