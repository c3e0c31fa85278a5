//! The board's three executors, by priority:
//! - the realtime one, polled from an otherwise unused device interrupt ([`REALTIME_IRQ`], the
//!   8350's I/O loop, `Board::realtime`), which preempts the others;
//! - the main one, polled from another ([`MAIN_IRQ`], at a lower priority): the network, the
//!   services, the 8318's acquisition;
//! - the background one, in thread mode on a stack of its own ([`BACKGROUND_STACK`], the process
//!   stack), which sleeps with WFI between polls (Embassy's WFE loop never sleeps under QEMU):
//!   work every other task preempts, MQTT's service with its TLS (`remodaq_mqtt::link`,
//!   docs/mqtt.md "Never in the way") and the services' offload worker.
//!
//! One pender serves them all: the background executor's context is null, the others' their
//! interrupt number. The main executor's interrupt and every other handler run on the main
//! stack, which the background executor's work (the TLS handshake's deep calls) never deepens.

use core::sync::atomic::{AtomicBool, AtomicPtr, Ordering};

use cortex_m::peripheral::NVIC;
use embassy_executor::{raw, SendSpawner, Spawner};
use static_cell::StaticCell;

use crate::irq::Irq;

static PENDING: AtomicBool = AtomicBool::new(true);

/// The realtime executor's interrupt: nothing of the machine is wired to it (mps2-an386's
/// devices use IRQs 0-15, ../shared/spec/qemu-board.md), so only the pender requests it.
pub const REALTIME_IRQ: u16 = 30;

/// The main executor's interrupt: unwired too.
pub const MAIN_IRQ: u16 = 31;

/// The main executor's interrupt priority: below every other interrupt (the LAN9118's, the
/// realtime executor's) and SysTick, all at the reset priority 0, which preempt it; above
/// thread mode (the background executor). The lowest of each implemented priority bits.
const MAIN_PRIORITY: u8 = 0xE0;

/// The realtime executor, once started (polled by its interrupt).
static REALTIME: AtomicPtr<raw::Executor> = AtomicPtr::new(core::ptr::null_mut());
/// The main executor (polled by its interrupt).
static MAIN: AtomicPtr<raw::Executor> = AtomicPtr::new(core::ptr::null_mut());
/// The background executor (polled in thread mode).
static BACKGROUND: AtomicPtr<raw::Executor> = AtomicPtr::new(core::ptr::null_mut());

/// The background executor's stack, bytes: the TLS handshake's calls, which reach 12 840 bytes
/// (docs/mqtt.md, "Sizes"; 29 940 before the broker's certificate was read in place). Outside
/// the STM32's 192 KiB that the rest of the image is held to (memory.x, the `BACKGROUND`
/// region): the STM32's plan has no room for it yet.
const BACKGROUND_BYTES: usize = 16 * 1024;

/// The background executor's stack ([`BACKGROUND_BYTES`]).
#[unsafe(link_section = ".background_stack")]
static mut BACKGROUND_STACK: [u64; BACKGROUND_BYTES / 8] = [0; BACKGROUND_BYTES / 8];

#[unsafe(export_name = "__pender")]
fn pender(context: *mut ()) {
    if context.is_null() {
        PENDING.store(true, Ordering::Release);
    } else {
        NVIC::pend(Irq(context as usize as u16));
    }
}

/// The background stack's bottom and top (its high-water mark: `crate::stack`).
pub fn background_stack() -> (usize, usize) {
    let bottom = core::ptr::addr_of!(BACKGROUND_STACK) as usize;
    (bottom, bottom + BACKGROUND_BYTES)
}

/// Hands `init` the background executor's spawner and the main one's (before the main one runs:
/// its first tasks; every later spawn on it from its own tasks), starts the main executor, then
/// runs the background executor in thread mode, forever.
pub fn run(init: impl FnOnce(Spawner, Spawner)) -> ! {
    static MAIN_EXECUTOR: StaticCell<raw::Executor> = StaticCell::new();
    static BACKGROUND_EXECUTOR: StaticCell<raw::Executor> = StaticCell::new();
    let main: &'static raw::Executor = MAIN_EXECUTOR.init(raw::Executor::new(usize::from(MAIN_IRQ) as *mut ()));
    let background: &'static raw::Executor = BACKGROUND_EXECUTOR.init(raw::Executor::new(core::ptr::null_mut()));
    MAIN.store(core::ptr::from_ref(main).cast_mut(), Ordering::Release);
    BACKGROUND.store(core::ptr::from_ref(background).cast_mut(), Ordering::Release);
    init(background.spawner(), main.spawner());
    let (bottom, top) = background_stack();
    // SAFETY: nothing runs on the background stack before the switch below.
    unsafe { crate::stack::paint(bottom, top) };
    // SAFETY: the NVIC's priority byte of an unwired interrupt (NVIC_IPR, ARMv7-M ARM B3.4.9),
    // written before it is unmasked (not through `Peripherals`, which the board takes later);
    // the executor it polls is stored above.
    unsafe {
        (*NVIC::PTR).ipr[usize::from(MAIN_IRQ)].write(MAIN_PRIORITY);
        NVIC::unmask(Irq(MAIN_IRQ));
    }
    NVIC::pend(Irq(MAIN_IRQ));
    // SAFETY: thread mode moves to the process stack, the top of BACKGROUND_STACK (8-aligned,
    // used by nothing else), and calls `background_loop`, which never returns: no frame of this
    // function is used again. Handlers keep the main stack (CONTROL.SPSEL applies to thread
    // mode only); the ISB makes the switch take effect before the call (ARMv7-M ARM, B1.4.4).
    unsafe {
        core::arch::asm!(
            "msr psp, r0",
            "mrs r1, control",
            "orr r1, r1, #2",
            "msr control, r1",
            "isb",
            "bl {entry}",
            in("r0") top,
            in("r1") 0u32,
            entry = sym background_loop,
            options(noreturn),
        )
    }
}

/// Thread mode on the background stack: polls the background executor, sleeping with WFI when
/// nothing was woken.
extern "C" fn background_loop() -> ! {
    // SAFETY: stored by `run` before it called this, from the `&'static` it made; never freed.
    let executor = unsafe { &*BACKGROUND.load(Ordering::Acquire) };
    loop {
        let started = crate::time::counter_us();
        // SAFETY: polled from thread mode only, never re-entered.
        unsafe { executor.poll() };
        crate::time::background_poll(crate::time::counter_us().wrapping_sub(started));
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

/// The main executor's interrupt handler: each poll's longest task poll said if long
/// (`crate::time::main_poll`).
pub(crate) extern "C" fn main_interrupt() {
    let executor = MAIN.load(Ordering::Acquire);
    if !executor.is_null() {
        crate::trace::poll_begins();
        // SAFETY: the executor is 'static (`run`); this handler is its only poller and an
        // interrupt does not preempt itself, so the poll is never re-entered.
        unsafe { (*executor).poll() };
        crate::time::main_poll(crate::trace::longest());
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
