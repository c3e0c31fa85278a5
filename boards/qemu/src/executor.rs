//! A thread-mode executor that sleeps with WFI between polls.

use core::sync::atomic::{AtomicBool, Ordering};

use embassy_executor::{raw, Spawner};
use static_cell::StaticCell;

static PENDING: AtomicBool = AtomicBool::new(true);

#[unsafe(export_name = "__pender")]
fn pender(_context: *mut ()) {
    PENDING.store(true, Ordering::Release);
}

/// Runs the executor forever after `init` has spawned the first tasks.
pub fn run(init: impl FnOnce(Spawner)) -> ! {
    static EXECUTOR: StaticCell<raw::Executor> = StaticCell::new();
    let executor: &'static raw::Executor = EXECUTOR.init(raw::Executor::new(core::ptr::null_mut()));
    init(executor.spawner());
    loop {
        // SAFETY: polled from thread mode only, never re-entered.
        unsafe { executor.poll() };
        // Sleep unless something was woken meanwhile. Interrupts are masked while checking, so
        // a wake-up between the check and WFI still ends the WFI (a pending interrupt does).
        cortex_m::interrupt::disable();
        if !PENDING.swap(false, Ordering::AcqRel) {
            cortex_m::asm::wfi();
        }
        // SAFETY: re-enables what was disabled just above.
        unsafe { cortex_m::interrupt::enable() };
    }
}
