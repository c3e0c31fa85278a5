//! Liveness of the firmware's tasks, for the watchdog: each watched task beats when it has
//! done its work; the watchdog task feeds the hardware watchdog only while every watched task
//! has beaten within a window. A task stuck (on a lock held too long, a stalled network stack)
//! thus ends in a reset, while a task that is merely late by less than the window (a settings
//! commit holding the register map for a few sector erases) does not.
//!
//! Times are milliseconds of the caller's clock, kept in 32 bits (they wrap after 49 days; the
//! comparisons are wrapping), since the Cortex-M4 has no 64-bit atomics.

use core::sync::atomic::{AtomicU32, Ordering};

/// Watched task: the network stack.
pub const NET: u32 = 1 << 0;
/// Watched task: the module application (the 8318 takes the register map's lock each cycle).
pub const APP: u32 = 1 << 1;
const TASKS: usize = 2;

/// The last beat of each watched task.
pub struct Heartbeat {
    last_ms: [AtomicU32; TASKS],
    beaten: AtomicU32,
    watched: u32,
}

impl Heartbeat {
    /// Watches the tasks whose bits are set in `watched` ([`NET`], [`APP`]).
    pub const fn new(watched: u32) -> Self {
        Self { last_ms: [const { AtomicU32::new(0) }; TASKS], beaten: AtomicU32::new(0), watched }
    }

    /// Task `bit` is alive at `now_ms`.
    pub fn beat(&self, bit: u32, now_ms: u64) {
        if let Some(slot) = self.last_ms.get(bit.trailing_zeros() as usize) {
            slot.store(now_ms as u32, Ordering::Relaxed);
            self.beaten.fetch_or(bit, Ordering::Relaxed);
        }
    }

    /// Every watched task has beaten, the last time within `window_ms` before `now_ms`.
    pub fn all_alive(&self, now_ms: u64, window_ms: u32) -> bool {
        if !self.all_started() {
            return false;
        }
        (0..TASKS).filter(|n| self.watched & (1 << n) != 0).all(|n| {
            let last = self.last_ms[n].load(Ordering::Relaxed);
            (now_ms as u32).wrapping_sub(last) <= window_ms
        })
    }

    /// Every watched task has beaten at least once since start-up.
    pub fn all_started(&self) -> bool {
        self.beaten.load(Ordering::Relaxed) & self.watched == self.watched
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn alive_only_while_every_task_beat_within_the_window() {
        let h = Heartbeat::new(NET | APP);
        assert!(!h.all_alive(0, 3000), "nothing beat yet");
        h.beat(NET, 100);
        assert!(!h.all_alive(100, 3000) && !h.all_started(), "APP never beat");
        h.beat(APP, 200);
        assert!(h.all_started());
        assert!(h.all_alive(3100, 3000), "NET 3.0 s ago: inside the window");
        assert!(!h.all_alive(3101, 3000), "NET 3.001 s ago: outside");
        h.beat(NET, 3050);
        assert!(h.all_alive(3200, 3000));
        assert!(!h.all_alive(3201, 3000), "APP 3.001 s ago");
    }

    #[test]
    fn wrapping_milliseconds() {
        let h = Heartbeat::new(APP);
        let t = u64::from(u32::MAX) - 10;
        h.beat(APP, t);
        assert!(h.all_alive(t + 2000, 3000), "across the 32-bit wrap");
        assert!(!h.all_alive(t + 4000, 3000));
    }
}
