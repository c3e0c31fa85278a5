//! The 8350's terminals on the host board: the scenario file's input signals sampled in
//! simulated time at the module's sample rate, and the outputs played at its tick rate (level
//! changes logged at debug level), through the module's own engines.

use remodaq_8350::di::SAMPLE_RATE_HZ;
use remodaq_8350::io::{SimulatedCapture, SimulatedPattern};
use remodaq_8350::M8350;
use remodaq_shared::board::IoFor;

use crate::scenario::{parse_digital, Digital, Watched};
use crate::{fail, HostBoard, Scenario};

/// The simulated input capture: sample `index` of the scenario's signals.
pub type Capture = SimulatedCapture<Box<dyn FnMut(u64) -> Option<u16>>>;
/// The simulated output pattern: logs every change of the output levels.
pub type Pattern = SimulatedPattern<Box<dyn FnMut(&[u8])>>;

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
        let sample_at = move |index: u64| {
            // The file is checked every 10 ms of samples.
            if index >= next_refresh {
                next_refresh = index + u64::from(SAMPLE_RATE_HZ) / 100;
                if let Some(watched) = scenario.as_mut() {
                    current = watched.refresh().clone();
                }
            }
            (!current.lose_samples).then(|| current.sample_at(index as f64 / rate))
        };
        let mut last = 0u8;
        let played = move |ticks: &[u8]| {
            for &levels in ticks {
                if levels != last {
                    log::debug!("DO levels {levels:06b}");
                    last = levels;
                }
            }
        };
        (SimulatedCapture::new(Box::new(sample_at)), SimulatedPattern::new(Box::new(played)))
    }
}
