//! The 8350's terminals on the QEMU board: a simulated capture (a 1 kHz square wave on DI0, DI3
//! steady high; samples lost from 20 s to 23 s after the start) sampled at the module's rate
//! in simulated time through a ring of the STM32's size (it overruns when the application
//! drains it late, as the DMA ring does), and the outputs played at its tick rate, through the
//! same engines and I/O loop as on the STM32.

use embassy_time::Instant;
use remodaq_8350::di::SAMPLE_RATE_HZ;
use remodaq_8350::io::{OutputPattern, PatternUnderrun, SimulatedCapture, SimulatedPattern, CAPTURE_RING};
use remodaq_8350::M8350;
use remodaq_shared::board::IoFor;

use crate::QemuBoard;

/// Square wave on DI0, Hz.
pub const DI0_HZ: u64 = 1000;

/// The capture loses its samples from 20 s to 23 s after the start (an injected front-end
/// fault, for the diagnostics registers' end-to-end test).
pub const LOST_SAMPLES_S: core::ops::Range<u64> = 20..23;

/// DI0 high in the second half of each period; DI3 steady high; nothing in the loss window.
fn sample_at(index: u64) -> Option<u16> {
    if LOST_SAMPLES_S.contains(&(index / u64::from(SAMPLE_RATE_HZ))) {
        return None;
    }
    let di0 = (index * DI0_HZ * 2 / u64::from(SAMPLE_RATE_HZ)) % 2 == 1;
    Some(u16::from(di0) | 0b1000)
}

fn played(_: u64, _: &[u8]) {}

/// The simulated output ring, which says in QEMU's log when and how it ran dry, so a test can
/// tell a stall of the PC (`time.rs` says those) from a late refill by the firmware.
pub struct Pattern(SimulatedPattern<fn(u64, &[u8])>);

impl OutputPattern for Pattern {
    async fn room(&mut self) {
        self.0.room().await;
    }

    fn write(&mut self, ticks: &[u8]) -> Result<u32, PatternUnderrun> {
        let written = self.0.write(ticks);
        if written.is_err() {
            cortex_m_semihosting::hprintln!(
                "qemu board: the output pattern ran dry, at {} us",
                Instant::now().as_micros()
            );
        }
        written
    }

    fn force(&mut self, mask: u8, levels: u8) -> u32 {
        self.0.force(mask, levels)
    }
}

impl IoFor<M8350> for QemuBoard {
    type Io = (SimulatedCapture<fn(u64) -> Option<u16>>, Pattern);

    fn io((): ()) -> Self::Io {
        (
            SimulatedCapture::with_ring(sample_at as fn(u64) -> Option<u16>, CAPTURE_RING),
            Pattern(SimulatedPattern::new(played as fn(u64, &[u8]))),
        )
    }
}
