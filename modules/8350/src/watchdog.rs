//! The host watchdog (extensions §3): when no feeding request arrived for the timeout, the
//! outputs go to their safe levels. Plain logic on the module's clock ([`Instant`]), so it
//! behaves the same on every board; the I/O loop polls it every 2 ms and the register map
//! feeds it with each request.

use embassy_time::{Duration, Instant};
use remodaq_protocol::m8350::wd_mode;

/// The watchdog's persisted settings (registers 40305 and 40307).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct WatchdogConfig {
    /// Timeout in 0.1 s; 0 = off.
    pub timeout: u16,
    /// Mode bits ([`wd_mode`]).
    pub mode: u16,
}

/// The watchdog's state.
#[derive(Clone, Copy, Debug)]
pub struct HostWatchdog {
    config: WatchdogConfig,
    /// Armed by the first feeding request after start-up.
    armed: bool,
    last_feed: Instant,
    tripped: bool,
}

impl HostWatchdog {
    /// A watchdog after start-up: not armed, not tripped.
    pub fn new(config: WatchdogConfig, now: Instant) -> Self {
        Self { config, armed: false, last_feed: now, tripped: false }
    }

    /// Takes new settings; a change takes effect at once and re-arms the timer from `now`.
    pub fn configure(&mut self, config: WatchdogConfig, now: Instant) {
        if config != self.config {
            self.config = config;
            self.last_feed = now;
        }
    }

    /// A request arrived (`write`: function 05, 06, 15 or 16) at `now`. Returns true when it
    /// ended the safe state (automatic clear).
    pub fn request(&mut self, write: bool, now: Instant) -> bool {
        if self.config.mode & wd_mode::WRITES_ONLY != 0 && !write {
            return false;
        }
        self.armed = true;
        self.last_feed = now;
        if self.tripped && self.config.mode & wd_mode::AUTO_CLEAR != 0 {
            self.tripped = false;
            return true;
        }
        false
    }

    /// Checks the timer at `now`; true when the watchdog trips now.
    pub fn poll(&mut self, now: Instant) -> bool {
        let timeout = Duration::from_millis(100 * u64::from(self.config.timeout));
        if self.tripped || !self.armed || self.config.timeout == 0 || now < self.last_feed + timeout {
            return false;
        }
        self.tripped = true;
        true
    }

    /// Ends the safe state (0 written to 40308).
    pub fn clear(&mut self) {
        self.tripped = false;
    }

    /// Whether the outputs are in the safe state.
    pub fn tripped(&self) -> bool {
        self.tripped
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    const HALF_SECOND: WatchdogConfig = WatchdogConfig { timeout: 5, mode: 0 };

    #[test]
    fn armed_by_the_first_feed_trips_after_the_timeout() {
        let mut wd = HostWatchdog::new(HALF_SECOND, at(0));
        assert!(!wd.poll(at(10_000)), "never fed: not armed, no trip");
        assert!(!wd.request(false, at(10_000)));
        assert!(!wd.poll(at(10_499)));
        assert!(wd.poll(at(10_500)), "0.5 s after the last feed");
        assert!(wd.tripped());
        assert!(!wd.poll(at(10_600)), "trips once");
        assert!(!wd.request(false, at(10_700)), "manual clear: a request does not end it");
        assert!(wd.tripped());
        wd.clear();
        assert!(!wd.tripped());
    }

    #[test]
    fn writes_only_and_automatic_clear() {
        let config = WatchdogConfig { timeout: 5, mode: wd_mode::WRITES_ONLY | wd_mode::AUTO_CLEAR };
        let mut wd = HostWatchdog::new(config, at(0));
        wd.request(true, at(0));
        wd.request(false, at(400));
        assert!(wd.poll(at(500)), "reads do not feed in writes-only mode");
        assert!(!wd.request(false, at(600)), "a read does not clear either");
        assert!(wd.request(true, at(700)), "the next write ends the safe state");
        assert!(!wd.tripped());
        assert!(!wd.poll(at(1199)) && wd.poll(at(1200)));
    }

    #[test]
    fn off_and_reconfigured() {
        let mut wd = HostWatchdog::new(WatchdogConfig::default(), at(0));
        wd.request(false, at(0));
        assert!(!wd.poll(at(1_000_000)), "timeout 0: off");
        wd.configure(HALF_SECOND, at(2_000_000));
        assert!(!wd.poll(at(2_000_499)), "re-armed from the change");
        assert!(wd.poll(at(2_000_500)));
    }
}
