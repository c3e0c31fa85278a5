//! The 8318's terminals on the QEMU board, fixed so that the test command can check them
//! against the spec: ch0 a type K thermocouple at 100 °C (4.096 mV by the NIST table, less the
//! cold junction's 1.000 mV at 25 °C), ch1 20 mV, ch2 12 mA, ch3 open, ch4 a 0..10 mV ramp over
//! 10 s (so values move), the rest 0 mV; terminals at 25 °C. From 20 s to 23 s after the start
//! every conversion fails (an injected front-end fault, for the diagnostics registers'
//! end-to-end test); with the test switch `FRONT_END_FAULT` set (`crate::test_switches`), every
//! conversion fails, always (a broken front end, for the update self-test's test).

use embassy_time::Instant;
use remodaq_8318::acquisition::{AnalogFrontEnd, Measurement};
use remodaq_8318::input::SHUNT_OHMS;
use remodaq_8318::M8318;
use remodaq_shared::board::IoFor;

use crate::QemuBoard;

/// The simulated front end.
pub struct Simulated;

impl IoFor<M8318> for QemuBoard {
    type Io = Simulated;

    fn io((): ()) -> Simulated {
        Simulated
    }
}

/// Seconds after the start during which the front end fails.
pub const FAULT_S: core::ops::Range<u64> = 20..23;

impl AnalogFrontEnd for Simulated {
    type Error = &'static str;

    async fn measure(&mut self, channel: u8, _span_mv: f64, _detect_open: bool) -> Result<Measurement, Self::Error> {
        if crate::test_switches::front_end_fault() {
            return Err("the front end is broken (test switch)");
        }
        if FAULT_S.contains(&Instant::now().as_secs()) {
            return Err("injected front-end fault");
        }
        Ok(match channel {
            0 => Measurement::Millivolts(4.096 - 1.000),
            1 => Measurement::Millivolts(20.0),
            2 => Measurement::Millivolts(12.0 * SHUNT_OHMS),
            3 => Measurement::Open,
            4 => Measurement::Millivolts((Instant::now().as_millis() % 10_000) as f64 / 1000.0),
            _ => Measurement::Millivolts(0.0),
        })
    }

    async fn cold_junction_c(&mut self) -> Result<f64, Self::Error> {
        Ok(25.0)
    }
}
