//! Liveness of the firmware's tasks, for the watchdog: each watched task beats regularly; the
//! watchdog task feeds the hardware watchdog only when every watched task has beaten since the
//! last check. A task stuck on a lock, or a stalled network stack, thus ends in a reset.

use core::sync::atomic::{AtomicU32, Ordering};

/// Bit set of watched tasks that have beaten since the last check.
pub struct Heartbeat {
    beats: AtomicU32,
    watched: u32,
}

impl Heartbeat {
    /// Watches the tasks whose bits are set in `watched`.
    pub const fn new(watched: u32) -> Self {
        Self { beats: AtomicU32::new(0), watched }
    }

    /// Task `bit` is alive.
    pub fn beat(&self, bit: u32) {
        self.beats.fetch_or(bit, Ordering::Relaxed);
    }

    /// True (and the record cleared) when every watched task beat since the last call.
    pub fn all_alive(&self) -> bool {
        let beats = self.beats.swap(0, Ordering::Relaxed);
        beats & self.watched == self.watched
    }
}

/// Watched task: the network stack.
pub const NET: u32 = 1 << 0;
/// Watched task: the module application (it takes the register map's lock each cycle).
pub const APP: u32 = 1 << 1;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn feeds_only_when_all_beat() {
        let h = Heartbeat::new(NET | APP);
        assert!(!h.all_alive());
        h.beat(NET);
        assert!(!h.all_alive());
        h.beat(NET);
        h.beat(APP);
        assert!(h.all_alive());
        assert!(!h.all_alive());
    }
}
