//! A rate budget: a burst of events, then one more every so many milliseconds. The flash commit
//! budgets (`settings::SettingsStore::take`: Modbus writes, authenticated changes) and the
//! discovery service's broadcast replies draw on one each.

/// A burst of `burst` events at once, then one more every `refill_ms`; an event beyond it is
/// refused and takes nothing. Kept as the time at which the budget is full again, so taking
/// and refilling are one comparison and one addition, without a timer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Budget {
    burst: u32,
    refill_ms: u64,
    full_at: u64,
}

impl Budget {
    /// A full budget.
    pub const fn new(burst: u32, refill_ms: u64) -> Self {
        Self { burst, refill_ms, full_at: 0 }
    }

    /// A budget holding only `available` events at `now_ms` (at most `burst`), refilled from
    /// then on.
    pub const fn holding(burst: u32, refill_ms: u64, available: u32, now_ms: u64) -> Self {
        let missing = burst.saturating_sub(available);
        Self { burst, refill_ms, full_at: now_ms + missing as u64 * refill_ms }
    }

    /// A budget that owes `debt_ms` at `now_ms` (what [`Budget::debt`] said before a restart),
    /// at most a whole burst's worth: nothing in it until the debt is paid down to below one
    /// refill.
    pub const fn owing(burst: u32, refill_ms: u64, debt_ms: u64, now_ms: u64) -> Self {
        let whole = burst as u64 * refill_ms;
        let debt = if debt_ms < whole { debt_ms } else { whole };
        Self { burst, refill_ms, full_at: now_ms + debt }
    }

    /// How long, from `now_ms`, until the budget is full again (0: full).
    pub fn debt(&self, now_ms: u64) -> u64 {
        self.full_at.saturating_sub(now_ms)
    }

    /// Takes one event at `now_ms` even when the budget is spent (an event that must not be
    /// refused but must still count: the events after it wait the longer).
    pub fn draw(&mut self, now_ms: u64) {
        self.full_at = self.full_at.max(now_ms) + self.refill_ms;
    }

    /// Takes one event at `now_ms`; false (nothing taken) when the budget is spent.
    pub fn take(&mut self, now_ms: u64) -> bool {
        let debt = self.full_at.saturating_sub(now_ms);
        if debt + self.refill_ms > u64::from(self.burst) * self.refill_ms {
            return false;
        }
        self.draw(now_ms);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_burst_then_one_per_refill() {
        let mut b = Budget::new(3, 100);
        assert!((0..3).all(|_| b.take(1000)), "the burst");
        assert!(!b.take(1000), "spent");
        assert!(!b.take(1099), "not refilled yet");
        assert!(b.take(1100), "one more after a refill");
        assert!(!b.take(1100));
        let mut h = Budget::holding(3, 100, 1, 1000);
        assert!(h.take(1000));
        assert!(!h.take(1000), "held only one");
        assert!(h.take(1100) && h.take(1200) && h.take(1300) && !h.take(1300), "then refilled one at a time");
    }

    #[test]
    fn a_debt_carried_over_a_restart() {
        // Spent at 5000 ms: the next event is due one refill later.
        let mut b = Budget::new(3, 100);
        assert!((0..3).all(|_| b.take(5000)) && !b.take(5000));
        assert_eq!(b.debt(5000), 300, "three refills until full");
        // A restart: the clock starts at 0 again, the debt stays.
        let mut r = Budget::owing(3, 100, b.debt(5000), 0);
        assert!(!r.take(0) && !r.take(99), "nothing renewed by the restart");
        assert!(r.take(100) && !r.take(100));
        // A debt beyond a burst's worth counts as a burst's worth.
        let mut o = Budget::owing(3, 100, 10_000, 0);
        assert!(!o.take(99) && o.take(100) && !o.take(100));
        // A drawn event always goes through, and delays the next one.
        let mut d = Budget::new(1, 100);
        assert!(d.take(0));
        d.draw(0);
        assert_eq!(d.debt(0), 200);
        assert!(!d.take(100) && d.take(200));
    }
}
