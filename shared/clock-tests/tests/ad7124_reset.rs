//! The AD7124-8 driver waits out the chip's reset on the chip's own clock: the fake chip
//! (`modules/8318/tests/support/fake_ad7124.rs`) stays in reset for 2 ms of embassy-time, here
//! a mock clock that moves only while the driver waits on a timer. A driver that configured
//! the chip without waiting would have its writes lost however slow the machine, and init
//! would fail its read-back.

use std::future::Future;
use std::pin::pin;
use std::task::{Context, Poll, Waker};

use embassy_time::{Duration, Instant, MockDriver};
use remodaq_8318::ad7124::{reg, Ad7124};

#[path = "../../../modules/8318/tests/support/fake_ad7124.rs"]
mod fake;
use fake::FakeChip;

/// Runs `future` to completion, moving the mock clock 100 µs each time it waits: time passes
/// only while the code under test waits.
fn run<F: Future>(future: F) -> F::Output {
    let clock = MockDriver::get();
    let mut future = pin!(future);
    let mut cx = Context::from_waker(Waker::noop());
    for _ in 0..1_000_000 {
        if let Poll::Ready(output) = future.as_mut().poll(&mut cx) {
            return output;
        }
        clock.advance(Duration::from_micros(100));
    }
    panic!("never finished");
}

#[test]
fn init_configures_only_after_the_reset_on_the_chip_clock() {
    MockDriver::get().reset();
    let start = Instant::now();
    let mut adc = Ad7124::new(FakeChip::new());
    run(adc.init()).expect("init: the settings written after the reset, and read back");
    let took = start.elapsed();
    let chip = adc.into_inner();
    assert_eq!(chip.regs.get(&reg::FILTER_0), Some(&30), "FILTER_0 kept, not its reset value 060180h");
    assert_eq!(chip.regs.get(&(reg::FILTER_0 + 1)), Some(&4));
    assert!(took >= Duration::from_millis(2), "the reset lasts 2 ms of the chip's clock: init took {took:?}");
}
