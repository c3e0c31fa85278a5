//! The 8350 on the STM32 board (Nucleo-F429ZI reference hardware).

use defmt_rtt as _;
use panic_probe as _;

use core::cell::RefCell;

use embassy_executor::Spawner;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::{Duration, Ticker};
use remodaq_8350::di::SAMPLE_RATE_HZ;
use remodaq_8350::io::{self, Io, IoCell};
use remodaq_8350::map::Map8350;
use remodaq_8350::pulse::TICK_HZ;
use remodaq_8350::settings::Settings;
use remodaq_board_stm32::digital::{self, InputCapture, OutputPattern, PATTERN_LEN};
use remodaq_board_stm32::{spawn, SettingsFlash, HEARTBEAT, SETTINGS_SIZE};
use remodaq_shared::settings::SettingsStore;
use remodaq_shared::{error, health};
use static_cell::StaticCell;

type Map = Mutex<CriticalSectionRawMutex, Map8350<'static, SettingsFlash, CriticalSectionRawMutex>>;

remodaq_shared::embassy_net_tasks!(Map, remodaq_board_stm32::discovery::run);
type Cell = IoCell<CriticalSectionRawMutex>;

static MAP: StaticCell<Map> = StaticCell::new();
static IO: StaticCell<Cell> = StaticCell::new();

// The engines and the board's hardware paths must agree on their rates.
const _: () = assert!(digital::SAMPLE_RATE_HZ == SAMPLE_RATE_HZ && digital::TICK_HZ == TICK_HZ);

/// Starts the module's tasks.
pub async fn run(spawner: Spawner) {
    let (board, settings_flash, io) = remodaq_board_stm32::init();
    let mut store = SettingsStore::<SettingsFlash, Settings>::open(
        settings_flash,
        const { SettingsStore::<SettingsFlash, Settings>::config(0..SETTINGS_SIZE) },
    )
    .await;
    board.factory_reset(&mut store).await;
    let net = store.get().net;
    let identity = board.identity(remodaq_8350::MODULE_NAME, remodaq_8350::MODEL, net);
    let cell: &'static Cell = IO.init(IoCell::new(RefCell::new(Io::new(SAMPLE_RATE_HZ, store.get()))));
    let map: &'static Map = MAP.init(Mutex::new(Map8350::new(store, cell)));
    let (capture, pattern) = io.digital.start(|ticks| io::with(cell, |s| s.pulse.fill(ticks)));
    let stack = board.start(&spawner, &net);
    spawn_network(&spawner, stack, net.port, map, identity);
    spawn(&spawner, input_task(capture, cell), "inputs");
    spawn(&spawner, output_task(pattern, cell), "outputs");
}

/// Drains the capture ring into the DI engine every 2 ms; each pass is the application's
/// heartbeat.
#[embassy_executor::task]
async fn input_task(mut capture: InputCapture, cell: &'static Cell) -> ! {
    let mut samples = [0u16; 512];
    let mut ticker = Ticker::every(Duration::from_millis(2));
    loop {
        ticker.next().await;
        loop {
            match capture.read(&mut samples) {
                Ok(0) => break,
                Ok(n) => io::with(cell, |s| s.di.process(&samples[..n])),
                Err(e) => {
                    error!("inputs: {:?}: samples were lost", e);
                    break;
                }
            }
        }
        HEARTBEAT.beat(health::APP);
    }
}

/// Keeps the output pattern filled from the pulse engine, half a pattern at a time.
#[embassy_executor::task]
async fn output_task(mut pattern: OutputPattern, cell: &'static Cell) -> ! {
    let mut ticks = [0u8; PATTERN_LEN / 2];
    loop {
        io::with(cell, |s| s.pulse.fill(&mut ticks));
        if let Err(e) = pattern.write(&ticks).await {
            error!("outputs: {:?}: the pattern ran dry", e);
        }
    }
}
