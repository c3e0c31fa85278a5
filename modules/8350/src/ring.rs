//! Where a circular DMA stands in the output pattern, in ticks since it started: the stream's
//! NDTR gives its place within one pass over the ring, and the time since the last look says
//! which pass (the pattern is read at exactly [`TICK_HZ`], from the same clock tree as the
//! time base). The STM32 board keeps its own write index against this ([`DmaPosition`]), so that
//! its pattern is written only through its own pointer (stm32 review R1), and a refill that
//! came too late is seen as what it is: the DMA past the last tick written.

use crate::pulse::TICK_HZ;

/// The ticks a circular DMA has read from a ring of `len` words since it started.
#[derive(Debug, Clone, Copy)]
pub struct DmaPosition {
    len: u64,
    read: u64,
    at_us: u64,
}

impl DmaPosition {
    /// A ring of `len` words whose DMA starts at its first word at `now_us` (µs of the time
    /// base).
    pub const fn new(len: usize, now_us: u64) -> Self {
        Self { len: len as u64, read: 0, at_us: now_us }
    }

    /// The ticks read since the start, from the stream's `remaining` transfers in this pass
    /// (NDTR: `len` at the start of a pass, 1 before its last word; RM0090 §10.5.6) seen at
    /// `now_us`: of the counts with that place in the ring, the one nearest what the time since
    /// the last look predicts, and never less than the last. Exact while the prediction errs by
    /// less than half the ring (here: by less than a tick).
    pub fn sync(&mut self, remaining: usize, now_us: u64) -> u64 {
        let len = self.len;
        let place = (len - (remaining as u64).min(len)) % len;
        let elapsed = now_us.saturating_sub(self.at_us).saturating_mul(u64::from(TICK_HZ)) / 1_000_000;
        let predicted = self.read.saturating_add(elapsed);
        let base = predicted - predicted % len + place;
        let nearest = [base.checked_sub(len), Some(base), base.checked_add(len)]
            .into_iter()
            .flatten()
            .min_by_key(|c| c.abs_diff(predicted))
            .unwrap_or(base);
        self.read = nearest.max(self.read);
        self.at_us = now_us;
        self.read
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One tick at 10 kHz, µs.
    const TICK: u64 = 100;
    const LEN: usize = 128;

    /// NDTR when the DMA has read `total` ticks of the ring: a pass reloads it with LEN.
    fn ndtr(total: u64) -> usize {
        LEN - (total % LEN as u64) as usize
    }

    #[test]
    fn follows_the_dma_across_passes() {
        let mut p = DmaPosition::new(LEN, 1_000);
        // Looked at every 10 ticks, then every 100 (less than a ring), for 5 passes.
        let mut t = 0;
        while t < 5 * LEN as u64 {
            t += if t < 200 { 10 } else { 100 };
            assert_eq!(p.sync(ndtr(t), 1_000 + t * TICK), t, "at tick {t}");
        }
    }

    #[test]
    fn a_look_between_ticks_and_a_late_one() {
        let mut p = DmaPosition::new(LEN, 0);
        // 40 ticks and a half: NDTR still says 40 read.
        assert_eq!(p.sync(ndtr(40), 40 * TICK + 50), 40);
        // 190 ticks later (more than a ring): the time says which pass.
        assert_eq!(p.sync(ndtr(230), 230 * TICK + 20), 230);
        // NDTR just reloaded (LEN: a new pass) at tick 256, or caught at 0.
        assert_eq!(p.sync(LEN, 256 * TICK), 256);
        assert_eq!(p.sync(0, 384 * TICK), 384);
    }

    #[test]
    fn never_goes_back() {
        let mut p = DmaPosition::new(LEN, 0);
        assert_eq!(p.sync(ndtr(10), 10 * TICK), 10);
        // A read of NDTR one transfer behind (read before the last look's): stays at 10.
        assert_eq!(p.sync(ndtr(9), 10 * TICK), 10);
    }
}
