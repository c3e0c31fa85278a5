//! The 8318 on the host board: a simulated module on the PC, its terminals described by the
//! scenario file.

use std::convert::Infallible;

use embassy_executor::Spawner;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use remodaq_8318::acquisition::{self, AnalogFrontEnd, Measurement};
use remodaq_8318::input::SHUNT_OHMS;
use remodaq_8318::map::Map8318;
use remodaq_8318::settings::Settings;
use remodaq_board_host::flash::FileFlash;
use remodaq_board_host::scenario::{parse_analog, Analog, Terminal, Watched};

type Map = Mutex<CriticalSectionRawMutex, Map8318<FileFlash>>;

remodaq_board_host::host_network_tasks!(Map);

/// Starts the simulated module's tasks.
pub async fn run(spawner: Spawner) {
    let started = remodaq_board_host::start::<Settings>(remodaq_8318::MODULE_NAME).await;
    let scenario = started
        .options
        .scenario
        .as_deref()
        .map(|path| Watched::load(path, parse_analog).unwrap_or_else(|e| remodaq_board_host::fail(&e)));
    let map: &'static Map = Box::leak(Box::new(Mutex::new(Map8318::new(started.store))));
    spawn_network(&spawner, started.listener, started.discovery, started.identity, map);
    match app_task(ScenarioFrontEnd { scenario, current: Analog::default() }, map) {
        Ok(token) => spawner.spawn(token),
        Err(e) => log::error!("cannot start the acquisition task: {e:?}"),
    }
}

#[embassy_executor::task]
async fn app_task(mut fe: ScenarioFrontEnd, map: &'static Map) -> ! {
    acquisition::run(&mut fe, map, || {}).await
}

/// The simulated analog front end: the scenario's terminals, re-read once per cycle.
struct ScenarioFrontEnd {
    scenario: Option<Watched<Analog>>,
    current: Analog,
}

impl AnalogFrontEnd for ScenarioFrontEnd {
    type Error = Infallible;

    async fn measure(&mut self, channel: u8, _span_mv: f64, _detect_open: bool) -> Result<Measurement, Self::Error> {
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
        Ok(self.current.cjc_celsius)
    }
}
