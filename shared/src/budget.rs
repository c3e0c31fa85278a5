//! A rate budget: a burst of events, then one more every so many milliseconds. The flash commit
//! budget of Modbus writes (`settings::SettingsStore::take_write`) and the discovery service's
//! broadcast replies draw on one each.

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

    /// Takes one event at `now_ms`; false (nothing taken) when the budget is spent.
    pub fn take(&mut self, now_ms: u64) -> bool {
        let debt = self.full_at.saturating_sub(now_ms);
        if debt + self.refill_ms > u64::from(self.burst) * self.refill_ms {
            return false;
        }
        self.full_at = self.full_at.max(now_ms) + self.refill_ms;
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
}
