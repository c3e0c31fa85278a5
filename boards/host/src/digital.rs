//! The 8350's terminals on the host board: the scenario file's input signals sampled in
//! simulated time at the module's sample rate, and the outputs played at its tick rate (level
//! changes logged at debug level), through the module's own engines. An input wired to an
//! output (`from_do`) samples the levels that output plays, as a jumper on the terminals would.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use remodaq_8350::di::SAMPLE_RATE_HZ;
use remodaq_8350::io::{SimulatedCapture, SimulatedPattern};
use remodaq_8350::pulse::TICK_HZ;
use remodaq_8350::M8350;
use remodaq_shared::board::IoFor;

use crate::scenario::{parse_digital, Digital, Signal, Watched};
use crate::{fail, HostBoard, Scenario};

/// The simulated input capture: sample `index` of the scenario's signals.
pub type Capture = SimulatedCapture<Box<dyn FnMut(u64) -> Option<u16> + Send>>;
/// The simulated output pattern: logs every change of the output levels.
pub type Pattern = SimulatedPattern<Box<dyn FnMut(u64, &[u8]) + Send>>;

/// The output levels played, as changes: (tick, levels from that tick on). The pattern is
/// queued ahead of its playing, and the capture reads samples up to the present, so a sample
/// always finds the level of its moment here.
#[derive(Default)]
struct Played(VecDeque<(u64, u8)>);

impl Played {
    /// A change to `levels` at `tick`.
    fn change(&mut self, tick: u64, levels: u8) {
        // A refill after an underrun starts later than the last change: ticks only go forward.
        if self.0.back().is_none_or(|&(at, _)| at <= tick) {
            self.0.push_back((tick, levels));
        }
    }

    /// Forgets the changes from `tick` on (the ticks from there are being rewritten), and
    /// returns the levels in force before it.
    fn rewind(&mut self, tick: u64) -> Option<u8> {
        while self.0.back().is_some_and(|&(at, _)| at >= tick) {
            self.0.pop_back();
        }
        self.0.back().map(|&(_, levels)| levels)
    }

    /// The levels at `tick`, forgetting the changes before the one in force (the capture reads
    /// forward).
    fn at(&mut self, tick: u64) -> u8 {
        while self.0.get(1).is_some_and(|&(at, _)| at <= tick) {
            self.0.pop_front();
        }
        self.0.front().filter(|&&(at, _)| at <= tick).map_or(0, |&(_, levels)| levels)
    }
}

impl IoFor<M8350> for HostBoard {
    type Io = (Capture, Pattern);

    /// Loads the scenario (`--scenario`); a missing or malformed file ends the process with
    /// status 2, naming the line. The file is read again when it changes.
    fn io(scenario: Scenario) -> (Capture, Pattern) {
        let mut scenario =
            scenario.0.as_deref().map(|path| Watched::load(path, parse_digital).unwrap_or_else(|e| fail(&e)));
        let mut current = Digital::default();
        let rate = f64::from(SAMPLE_RATE_HZ);
        let mut next_refresh = 0;
        let played = Arc::new(Mutex::new(Played::default()));
        let outputs = played.clone();
        let sample_at = move |index: u64| {
            // The file is checked every 10 ms of samples.
            if index >= next_refresh {
                next_refresh = index + u64::from(SAMPLE_RATE_HZ) / 100;
                if let Some(watched) = scenario.as_mut() {
                    current = watched.refresh().clone();
                }
            }
            if current.lose_samples {
                return None;
            }
            let mut sample = current.sample_at(index as f64 / rate);
            if current.inputs.iter().any(|s| matches!(s, Signal::FromDo(_))) {
                let tick = index * u64::from(TICK_HZ) / u64::from(SAMPLE_RATE_HZ);
                let levels = outputs.lock().map_or(0, |mut played| played.at(tick));
                for (n, input) in current.inputs.iter().enumerate() {
                    if let Signal::FromDo(m) = *input {
                        sample |= u16::from(levels >> m & 1) << n;
                    }
                }
            }
            Some(sample)
        };
        let played = move |first: u64, ticks: &[u8]| {
            let Ok(mut played) = played.lock() else { return };
            // The ticks from `first` on are these (a forced rewrite replaces queued ones).
            let mut last = played.rewind(first);
            for (i, &levels) in ticks.iter().enumerate() {
                if last != Some(levels) {
                    log::debug!("DO levels {levels:06b}");
                    last = Some(levels);
                    played.change(first + i as u64, levels);
                }
            }
        };
        (SimulatedCapture::new(Box::new(sample_at)), SimulatedPattern::new(Box::new(played)))
    }
}
