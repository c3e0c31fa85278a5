//! The board's two executors: the main one in thread mode, which sleeps with WFI between polls
//! (Embassy's WFE loop never sleeps under QEMU), and the realtime one, polled from an
//! otherwise unused device interrupt ([`REALTIME_IRQ`]), which preempts it (the 8350's I/O
//! loop, `Board::realtime`). One pender serves both: the main executor's context is null, the
//! realtime one's is its interrupt number.

use core::sync::atomic::{AtomicBool, AtomicPtr, Ordering};

use cortex_m::peripheral::NVIC;
use embassy_executor::{raw, SendSpawner, Spawner};
use static_cell::StaticCell;

use crate::irq::Irq;

static PENDING: AtomicBool = AtomicBool::new(true);

/// The realtime executor's interrupt: nothing of the machine is wired to it (mps2-an386's
/// devices use IRQs 0-15, ../shared/spec/qemu-board.md), so only the pender requests it.
pub const REALTIME_IRQ: u16 = 30;

/// The realtime executor, once started (polled by its interrupt).
static REALTIME: AtomicPtr<raw::Executor> = AtomicPtr::new(core::ptr::null_mut());

#[unsafe(export_name = "__pender")]
fn pender(context: *mut ()) {
    if context.is_null() {
        PENDING.store(true, Ordering::Release);
    } else {
        NVIC::pend(Irq(context as usize as u16));
    }
}

/// Runs the executor forever after `init` has spawned the first tasks.
pub fn run(init: impl FnOnce(Spawner)) -> ! {
    static EXECUTOR: StaticCell<raw::Executor> = StaticCell::new();
    let executor: &'static raw::Executor = EXECUTOR.init(raw::Executor::new(core::ptr::null_mut()));
    init(executor.spawner());
    loop {
        let started = crate::time::counter_us();
        // SAFETY: polled from thread mode only, never re-entered.
        unsafe { executor.poll() };
        crate::time::main_poll(crate::time::counter_us().wrapping_sub(started));
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

/// Starts the realtime executor (once; a second call gets the same executor's spawner).
pub fn realtime() -> SendSpawner {
    static EXECUTOR: StaticCell<raw::Executor> = StaticCell::new();
    let started = REALTIME.load(Ordering::Acquire);
    if !started.is_null() {
        // SAFETY: the pointer was made from the `&'static` below and is never freed.
        return unsafe { &*started }.spawner().make_send();
    }
    let executor: &'static raw::Executor = EXECUTOR.init(raw::Executor::new(usize::from(REALTIME_IRQ) as *mut ()));
    REALTIME.store(core::ptr::from_ref(executor).cast_mut(), Ordering::Release);
    // SAFETY: the vector table's entry for REALTIME_IRQ polls this executor; unmasked once it
    // is stored. It runs at the reset priority (0), as the LAN9118's interrupt: neither nests.
    unsafe { NVIC::unmask(Irq(REALTIME_IRQ)) };
    executor.spawner().make_send()
}

/// The realtime executor's interrupt handler.
pub(crate) extern "C" fn realtime_interrupt() {
    let executor = REALTIME.load(Ordering::Acquire);
    if !executor.is_null() {
        // SAFETY: the executor is 'static (above); this handler is its only poller and an
        // interrupt does not preempt itself, so the poll is never re-entered.
        unsafe { (*executor).poll() };
    }
}
