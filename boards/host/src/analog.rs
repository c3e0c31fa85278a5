//! The 8318's terminals on the host board: the scenario file's voltages, currents and open
//! inputs, through the module's own acquisition cycle.

use remodaq_8318::acquisition::{AnalogFrontEnd, Measurement};
use remodaq_8318::input::SHUNT_OHMS;
use remodaq_8318::M8318;
use remodaq_shared::board::IoFor;

use crate::scenario::{parse_analog, Analog, Terminal, Watched};
use crate::{fail, HostBoard, Scenario};

/// The simulated analog front end: the scenario's terminals, re-read once per cycle.
pub struct ScenarioFrontEnd {
    scenario: Option<Watched<Analog>>,
    current: Analog,
}

impl IoFor<M8318> for HostBoard {
    type Io = ScenarioFrontEnd;

    /// Loads the scenario (`--scenario`); a missing or malformed file ends the process with
    /// status 2, naming the line.
    fn io(scenario: Scenario) -> ScenarioFrontEnd {
        let scenario = scenario.0.as_deref().map(|path| Watched::load(path, parse_analog).unwrap_or_else(|e| fail(&e)));
        ScenarioFrontEnd { scenario, current: Analog::default() }
    }
}

impl AnalogFrontEnd for ScenarioFrontEnd {
    type Error = &'static str;

    async fn measure(&mut self, channel: u8, _span_mv: f64, _detect_open: bool) -> Result<Measurement, Self::Error> {
        if self.current.frontend_fault {
            return Err("front-end fault injected by the scenario");
        }
        Ok(match self.current.channels[usize::from(channel) % 8] {
            Terminal::Millivolts(mv) => Measurement::Millivolts(mv),
            Terminal::Volts(v) => Measurement::Millivolts(v * 1000.0),
            Terminal::Milliamps(ma) => Measurement::Millivolts(ma * SHUNT_OHMS),
            Terminal::Open => Measurement::Open,
        })
    }

    /// Called first in every cycle: the moment to pick up a changed scenario file.
    async fn cold_junction_c(&mut self) -> Result<f64, Self::Error> {
        if let Some(watched) = self.scenario.as_mut() {
            self.current = watched.refresh().clone();
        }
        if self.current.cjc_fault {
            return Err("cold-junction fault injected by the scenario");
        }
        Ok(self.current.cjc_celsius)
    }
}
