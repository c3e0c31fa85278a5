//! The frame statistics of the responsiveness report (`REMODAQ_UTILITY_STATS`).

use std::time::Duration;

/// Frames not counted in the statistics after the warm-up (they build the font atlas and lay
/// out every view once).
pub const WARM_UP: u64 = 10;

/// The frames drawn, the longest UI pass (all the app does in a frame), and after the first
/// [`WARM_UP`] frames the longest UI pass and the whole frames as the window's integration
/// measures them (the UI, tessellation and painting, without the wait for the screen).
#[derive(Default)]
pub struct FrameStats {
    pub frames: u64,
    pub longest_ui: Duration,
    pub longest_ui_warm: Duration,
    /// Whole frames measured after the warm-up, the longest (s), those over 16 ms (a 60 Hz
    /// screen's frame) and their sum (s).
    whole: u64,
    longest_whole: f32,
    slow_whole: u64,
    whole_sum: f64,
}

impl FrameStats {
    /// One UI pass that took `took`.
    pub(super) fn ui_pass(&mut self, took: Duration) {
        self.frames += 1;
        self.longest_ui = self.longest_ui.max(took);
        if self.frames > WARM_UP {
            self.longest_ui_warm = self.longest_ui_warm.max(took);
        }
    }

    /// The previous whole frame's time, s.
    pub(super) fn whole_frame(&mut self, s: f32) {
        if self.frames > WARM_UP {
            self.whole += 1;
            self.longest_whole = self.longest_whole.max(s);
            self.slow_whole += u64::from(s > 0.016);
            self.whole_sum += f64::from(s);
        }
    }

    /// The line `scripts/utility-report` reads.
    pub(super) fn line(&self) -> String {
        format!(
            "frames {} longest_ui_ms {:.3} longest_after_warm_up_ms {:.3} longest_frame_after_warm_up_ms {:.3} slower_than_16ms {} mean_frame_ms {:.3}\n",
            self.frames,
            self.longest_ui.as_secs_f64() * 1e3,
            self.longest_ui_warm.as_secs_f64() * 1e3,
            self.longest_whole * 1e3,
            self.slow_whole,
            self.whole_sum * 1e3 / self.whole.max(1) as f64
        )
    }
}
