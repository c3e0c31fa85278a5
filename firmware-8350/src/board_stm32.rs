//! The 8350 on the STM32 board (Nucleo-F429ZI reference hardware).

use defmt_rtt as _;
use panic_probe as _;

use embassy_executor::Spawner;
use embassy_net::Stack;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::{Duration, Ticker};
use remodaq_8350::map::Map8350;
use remodaq_8350::settings::Settings;
use remodaq_board_stm32::modbus::{connection_task, ModbusSlots};
use remodaq_board_stm32::{spawn, SettingsFlash, HEARTBEAT, SETTINGS_SIZE};
use remodaq_shared::health;
use remodaq_shared::modbus::server::{Slots, MAX_CONNECTIONS, SOCKETS};
use remodaq_shared::settings::SettingsStore;
use static_cell::StaticCell;

type Map = Mutex<CriticalSectionRawMutex, Map8350<SettingsFlash>>;

static MAP: StaticCell<Map> = StaticCell::new();
static SLOTS: ModbusSlots = Slots::new(MAX_CONNECTIONS);

/// Starts the module's tasks.
pub async fn run(spawner: Spawner) {
    let (board, settings_flash, _io) = remodaq_board_stm32::init();
    let store = SettingsStore::<SettingsFlash, Settings>::open(
        settings_flash,
        const { SettingsStore::<SettingsFlash, Settings>::config(0..SETTINGS_SIZE) },
    )
    .await;
    let net = store.get().net;
    let map: &'static Map = MAP.init(Mutex::new(Map8350::new(store)));
    let stack = board.start(&spawner, &net);
    for slot in 0..SOCKETS {
        spawn(&spawner, modbus_task(stack, net.port, map, slot), "modbus");
    }
    spawn(&spawner, app_task(map), "app");
}

#[embassy_executor::task(pool_size = SOCKETS)]
async fn modbus_task(stack: Stack<'static>, port: u16, map: &'static Map, slot: usize) -> ! {
    connection_task(stack, port, map, &SLOTS, slot).await
}

/// The application cycle (10 Hz): takes the register map's lock each cycle, so a request stuck
/// holding it stops the heartbeat and the watchdog resets the module.
#[embassy_executor::task]
async fn app_task(map: &'static Map) -> ! {
    let mut ticker = Ticker::every(Duration::from_millis(100));
    loop {
        ticker.next().await;
        drop(map.lock().await);
        HEARTBEAT.beat(health::APP);
    }
}
