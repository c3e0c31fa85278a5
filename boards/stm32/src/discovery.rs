//! The discovery service's effects on this board: identify blinks LD1 for 10 s; restart resets
//! the MCU once the reply has had time to leave.

use embassy_net::Stack;
use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, RawMutex};
use embassy_sync::mutex::Mutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Timer};
use remodaq_shared::discovery::{Effect, Identity};
use remodaq_shared::module::SettingsAccess;

/// Raised to blink the identify LED.
pub static IDENTIFY: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// Serves the discovery protocol forever.
pub async fn run<R: RawMutex, A: SettingsAccess>(stack: Stack<'static>, map: &Mutex<R, A>, identity: Identity) -> ! {
    remodaq_shared::embassy_net::discovery(stack, map, identity, async |effect| match effect {
        Effect::None => {}
        Effect::Identify => IDENTIFY.signal(()),
        Effect::Restart => {
            remodaq_shared::info!("restart requested");
            Timer::after(Duration::from_millis(300)).await;
            cortex_m::peripheral::SCB::sys_reset();
        }
    })
    .await
}
