//! The 8350 on the host board: a simulated module on the PC. Its inputs are the scenario
//! file's signals, sampled in simulated time at the boards' sample rate and fed through the same
//! engine path as the STM32's captures; its outputs are computed tick by tick by the same pulse
//! engine and logged when they change.

use core::cell::RefCell;

use embassy_executor::Spawner;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::{Duration, Instant, Ticker};
use remodaq_8350::di::SAMPLE_RATE_HZ;
use remodaq_8350::io::{Io, IoCell, Simulation};
use remodaq_8350::map::Map8350;
use remodaq_8350::settings::Settings;
use remodaq_board_host::flash::FileFlash;
use remodaq_board_host::scenario::{parse_digital, Digital, Watched};

type Map = Mutex<CriticalSectionRawMutex, Map8350<'static, FileFlash, CriticalSectionRawMutex>>;

remodaq_board_host::host_network_tasks!(Map);
type Cell = IoCell<CriticalSectionRawMutex>;

/// Starts the simulated module's tasks.
pub async fn run(spawner: Spawner) {
    let started = remodaq_board_host::start::<Settings>(remodaq_8350::MODULE_NAME).await;
    let scenario = started
        .options
        .scenario
        .as_deref()
        .map(|path| Watched::load(path, parse_digital).unwrap_or_else(|e| remodaq_board_host::fail(&e)));
    let cell: &'static Cell =
        Box::leak(Box::new(IoCell::new(RefCell::new(Io::new(SAMPLE_RATE_HZ, started.store.get())))));
    let map: &'static Map = Box::leak(Box::new(Mutex::new(Map8350::new(started.store, cell))));
    spawn_network(&spawner, started.listener, started.discovery, started.identity, map);
    match io_task(scenario, cell) {
        Ok(token) => spawner.spawn(token),
        Err(e) => log::error!("cannot start the I/O task: {e:?}"),
    }
}

/// Every 5 ms: the input samples and output ticks that fell due since the last run.
#[embassy_executor::task]
async fn io_task(mut scenario: Option<Watched<Digital>>, cell: &'static Cell) -> ! {
    let start = Instant::now();
    let mut current = Digital::default();
    let mut simulation = Simulation::default();
    let mut last_levels = 0u8;
    let mut ticker = Ticker::every(Duration::from_millis(5));
    loop {
        ticker.next().await;
        if let Some(watched) = scenario.as_mut() {
            current = watched.refresh().clone();
        }
        let rate = f64::from(SAMPLE_RATE_HZ);
        simulation.advance(
            cell,
            start.elapsed().as_micros(),
            |index| current.sample_at(index as f64 / rate),
            |ticks| {
                for &levels in ticks {
                    if levels != last_levels {
                        log::debug!("DO levels {levels:06b}");
                        last_levels = levels;
                    }
                }
            },
        );
    }
}
