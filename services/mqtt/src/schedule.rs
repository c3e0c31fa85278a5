//! When a point is published (issue #40): when its value moved beyond its deadband since the
//! last publication, when its status changed, and at least once per period. Nothing queues: a
//! point that is due is published with its value as it stands then (docs/mqtt.md).

pub use remodaq_shared::mqtt::PERIOD_MS;

/// A point's last publication.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Point {
    /// The value and status published last, and when (ms); `None` before the first (and after
    /// a reconnect, when every point is published again).
    last: Option<(i64, u8, u64)>,
}

impl Point {
    /// A point not published yet.
    pub const fn new() -> Self {
        Self { last: None }
    }

    /// Whether `value` (in the point's units: thousandths of an engineering unit on the 8318,
    /// counts or levels on the 8350) with `status`, seen at `now_ms`, is to be published: it
    /// never was, its status changed, it moved by more than `deadband` from the value published
    /// last, or `period_ms` has passed since. A deadband of `u64::MAX` publishes on the period
    /// alone (the 8350 with on-change off); 0 on any change.
    pub fn due(&self, value: i64, status: u8, now_ms: u64, deadband: u64, period_ms: u32) -> bool {
        match self.last {
            None => true,
            Some((last, last_status, at)) => {
                status != last_status
                    || value.abs_diff(last) > deadband
                    || now_ms.saturating_sub(at) >= u64::from(period_ms)
            }
        }
    }

    /// Notes that `value` with `status` was published at `now_ms`.
    pub fn published(&mut self, value: i64, status: u8, now_ms: u64) {
        self.last = Some((value, status, now_ms));
    }

    /// Forgets the last publication (a new connection publishes every point at once).
    pub fn forget(&mut self) {
        self.last = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue #40: "no publish inside the deadband, one per period at the least".
    #[test]
    fn a_deadband_and_a_period() {
        let mut p = Point::new();
        assert!(p.due(1_000, 0, 0, 50, 1_000), "never published");
        p.published(1_000, 0, 0);
        // Inside the deadband (0.050 units either way): not due before the period.
        for (v, t) in [(1_050, 100), (950, 200), (1_000, 999)] {
            assert!(!p.due(v, 0, t, 50, 1_000), "{v} at {t}");
        }
        // Beyond it: due at once; the period: due with any value.
        assert!(p.due(1_051, 0, 10, 50, 1_000));
        assert!(p.due(949, 0, 10, 50, 1_000));
        assert!(p.due(1_000, 0, 1_000, 50, 1_000));
        // A status change is due whatever the value.
        assert!(p.due(1_000, 2, 10, 50, 1_000));
        // The deadband counts from the value published last, not the last seen.
        p.published(1_051, 0, 10);
        assert!(!p.due(1_100, 0, 20, 50, 1_000));
    }

    #[test]
    fn on_change_and_the_period_alone() {
        let mut p = Point::new();
        p.published(5, 0, 0);
        assert!(p.due(6, 0, 1, 0, 60_000), "on change: any change");
        assert!(!p.due(5, 0, 1, 0, 60_000));
        assert!(!p.due(6, 0, 1, u64::MAX, 60_000), "period alone: a change waits");
        assert!(p.due(5, 0, 60_000, u64::MAX, 60_000));
        // Counters far apart do not overflow the comparison.
        p.published(i64::MIN, 0, 0);
        assert!(p.due(i64::MAX, 0, 1, 0, 60_000));
        p.forget();
        assert!(p.due(5, 0, 1, u64::MAX, 60_000), "after a reconnect");
    }
}
