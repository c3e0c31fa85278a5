//! The 8318 on the QEMU board: the application of the STM32 board with a simulated front end.

use core::convert::Infallible;

use embassy_executor::Spawner;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::Instant;
use remodaq_8318::acquisition::{self, AnalogFrontEnd, Measurement};
use remodaq_8318::input::SHUNT_OHMS;
use remodaq_8318::map::Map8318;
use remodaq_8318::settings::Settings;
use remodaq_board_qemu::flash::{SettingsFlash, SIZE};
use remodaq_board_qemu::spawn;
use remodaq_shared::settings::SettingsStore;
use static_cell::StaticCell;

type Map = Mutex<CriticalSectionRawMutex, Map8318<SettingsFlash>>;

remodaq_shared::embassy_net_tasks!(Map, remodaq_board_qemu::discovery);

static MAP: StaticCell<Map> = StaticCell::new();

/// Starts the module's tasks.
pub async fn run(spawner: Spawner) {
    let (board, flash) = remodaq_board_qemu::init();
    let store = SettingsStore::<SettingsFlash, Settings>::open(
        flash,
        const { SettingsStore::<SettingsFlash, Settings>::config(0..SIZE as u32) },
    )
    .await;
    let port = store.get().net.port;
    let identity = board.identity(remodaq_8318::MODULE_NAME, remodaq_8318::MODEL, port);
    let map: &'static Map = MAP.init(Mutex::new(Map8318::new(store)));
    let stack = board.start(&spawner);
    spawn_network(&spawner, stack, port, map, identity);
    spawn(&spawner, app_task(map), "app");
}

#[embassy_executor::task]
async fn app_task(map: &'static Map) -> ! {
    acquisition::run(&mut Simulated, map, || {}).await
}

/// Deterministic terminals: ch0 a type K thermocouple at 100 °C (4.096 mV, less the cold
/// junction's 1.000 mV at 25 °C), ch1 20 mV, ch2 12 mA, ch3 open, ch4 a 0..10 mV ramp over 10 s
/// (so values move), the rest 0 mV; terminals at 25 °C.
struct Simulated;

impl AnalogFrontEnd for Simulated {
    type Error = Infallible;

    async fn measure(&mut self, channel: u8, _span_mv: f64, _detect_open: bool) -> Result<Measurement, Infallible> {
        Ok(match channel {
            0 => Measurement::Millivolts(4.096 - 1.000),
            1 => Measurement::Millivolts(20.0),
            2 => Measurement::Millivolts(12.0 * SHUNT_OHMS),
            3 => Measurement::Open,
            4 => Measurement::Millivolts((Instant::now().as_millis() % 10_000) as f64 / 1000.0),
            _ => Measurement::Millivolts(0.0),
        })
    }

    async fn cold_junction_c(&mut self) -> Result<f64, Infallible> {
        Ok(25.0)
    }
}
