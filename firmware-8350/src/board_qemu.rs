//! The 8350 on the QEMU board: the application of the STM32 board; the inputs are a simulated
//! capture (a 1 kHz square wave on DI0, DI3 steady high) sampled at the boards' rate in
//! simulated time, and the outputs' ticks are computed on the tick clock.

use core::cell::RefCell;

use embassy_executor::Spawner;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::{Duration, Instant, Ticker};
use remodaq_8350::di::SAMPLE_RATE_HZ;
use remodaq_8350::io::{Io, IoCell, Simulation};
use remodaq_8350::map::Map8350;
use remodaq_8350::settings::Settings;
use remodaq_board_qemu::flash::{SettingsFlash, SIZE};
use remodaq_board_qemu::spawn;
use remodaq_shared::settings::SettingsStore;
use static_cell::StaticCell;

type Map = Mutex<CriticalSectionRawMutex, Map8350<'static, SettingsFlash, CriticalSectionRawMutex>>;

remodaq_shared::embassy_net_tasks!(Map, remodaq_board_qemu::discovery);
type Cell = IoCell<CriticalSectionRawMutex>;

static MAP: StaticCell<Map> = StaticCell::new();
static IO: StaticCell<Cell> = StaticCell::new();

/// Square wave on DI0, Hz.
const DI0_HZ: u64 = 1000;

/// Starts the module's tasks.
pub async fn run(spawner: Spawner) {
    let (board, flash) = remodaq_board_qemu::init();
    let store = SettingsStore::<SettingsFlash, Settings>::open(
        flash,
        const { SettingsStore::<SettingsFlash, Settings>::config(0..SIZE as u32) },
    )
    .await;
    let port = store.get().net.port;
    let identity = board.identity(remodaq_8350::MODULE_NAME, remodaq_8350::MODEL, port);
    let cell: &'static Cell = IO.init(IoCell::new(RefCell::new(Io::new(SAMPLE_RATE_HZ, store.get()))));
    let map: &'static Map = MAP.init(Mutex::new(Map8350::new(store, cell)));
    let stack = board.start(&spawner);
    spawn_network(&spawner, stack, port, map, identity);
    spawn(&spawner, io_task(cell), "io");
}

/// Every 10 ms: the samples and ticks that fell due, through the same engines as on the STM32.
#[embassy_executor::task]
async fn io_task(cell: &'static Cell) -> ! {
    let start = Instant::now();
    let mut simulation = Simulation::default();
    let mut ticker = Ticker::every(Duration::from_millis(10));
    loop {
        ticker.next().await;
        // DI0: high in the second half of each period; DI3 steady high.
        let di0 = |index: u64| (index * DI0_HZ * 2 / u64::from(SAMPLE_RATE_HZ)) % 2 == 1;
        simulation.advance(cell, start.elapsed().as_micros(), |index| u16::from(di0(index)) | 0b1000, |_| {});
    }
}
