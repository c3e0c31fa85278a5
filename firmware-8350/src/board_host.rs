//! The 8350 on the host board: a simulated module on the PC.

use embassy_executor::Spawner;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use remodaq_8350::map::Map8350;
use remodaq_8350::settings::Settings;
use remodaq_board_host::flash::FileFlash;
use remodaq_board_host::modbus::{connection_task, Listener, ModbusSlots};
use remodaq_shared::modbus::server::{Slots, MAX_CONNECTIONS, SOCKETS};

type Map = Mutex<CriticalSectionRawMutex, Map8350<FileFlash>>;

static SLOTS: ModbusSlots = Slots::new(MAX_CONNECTIONS);

/// Starts the simulated module's tasks.
pub async fn run(spawner: Spawner) {
    let started = remodaq_board_host::start::<Settings>("8350", |s| s.net.port).await;
    let map: &'static Map = Box::leak(Box::new(Mutex::new(Map8350::new(started.store))));
    for slot in 0..SOCKETS {
        match modbus_task(started.listener, map, slot) {
            Ok(token) => spawner.spawn(token),
            Err(e) => log::error!("cannot start Modbus task {slot}: {e:?}"),
        }
    }
}

#[embassy_executor::task(pool_size = SOCKETS)]
async fn modbus_task(listener: &'static Listener, map: &'static Map, slot: usize) -> ! {
    connection_task(listener, map, &SLOTS, slot).await
}
