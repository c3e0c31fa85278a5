//! The module's time of day (docs/mqtt.md, "Time"): milliseconds since 1970, once a board or a
//! time server (SNTP, `remodaq_mqtt`'s embassy side) has said what it is; `None` before. Kept as
//! the time of day at the monotonic clock's zero, so that it runs on with `embassy_time`.

use core::cell::Cell;

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_time::Instant;

/// The time of day at `Instant` zero, ms since 1970; `None` until set.
static AT_ZERO_MS: Mutex<CriticalSectionRawMutex, Cell<Option<u64>>> = Mutex::new(Cell::new(None));

/// Says that it is `unix_ms` (ms since 1970) now.
pub fn set(unix_ms: u64) {
    let zero = unix_ms.saturating_sub(Instant::now().as_millis());
    AT_ZERO_MS.lock(|t| t.set(Some(zero)));
}

/// The time of day, ms since 1970; `None` before one was set.
pub fn now_ms() -> Option<u64> {
    AT_ZERO_MS.lock(|t| t.get()).map(|zero| zero + Instant::now().as_millis())
}

/// A time server: its IPv4 address and UDP port.
pub type Server = ([u8; 4], u16);

/// The time server the module asks (MQTT's settings name it); `None`: none.
static SERVER: Mutex<CriticalSectionRawMutex, Cell<Option<Server>>> = Mutex::new(Cell::new(None));

/// Signalled when the time server changed (the SNTP client asks the new one at once).
pub static SERVER_CHANGED: embassy_sync::signal::Signal<CriticalSectionRawMutex, ()> =
    embassy_sync::signal::Signal::new();

/// Names the time server (`None`: none).
pub fn set_server(server: Option<Server>) {
    if SERVER.lock(|s| s.replace(server)) != server {
        SERVER_CHANGED.signal(());
    }
}

/// The time server, if one is named.
pub fn server() -> Option<Server> {
    SERVER.lock(|s| s.get())
}
