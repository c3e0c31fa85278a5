//! embassy-executor's trace hooks (its feature `trace`, turned on by this board alone): the
//! longest task poll of each poll of the main executor, which the board's log says when long
//! (`crate::time::main_poll`), naming the task by its address (`llvm-nm -C` of the image gives the
//! pool it lies in): what to split when Modbus waits behind a task (issue #40, the worst latency
//! under QEMU). Only the main executor's tasks are timed: their hooks run in its
//! interrupt, told from the others' by the active exception (the one [`poll_begins`] saw).

use core::sync::atomic::{AtomicU32, Ordering};

/// When the task being polled began (µs, the board's counter), and which.
static STARTED: AtomicU32 = AtomicU32::new(0);
static TASK: AtomicU32 = AtomicU32::new(0);
/// The exception the main executor's poll runs in (SCB ICSR VECTACTIVE, ARMv7-M ARM B3.2.4).
static MAIN_EXCEPTION: AtomicU32 = AtomicU32::new(u32::MAX);
/// The longest task poll of the current executor poll: its length (µs) and its task.
static LONGEST_US: AtomicU32 = AtomicU32::new(0);
static LONGEST_TASK: AtomicU32 = AtomicU32::new(0);

/// The active exception's number (0 in thread mode).
fn active() -> u32 {
    // SAFETY: a read of ICSR (0xE000_ED04), which has no side effect.
    unsafe { (*cortex_m::peripheral::SCB::PTR).icsr.read() & 0x1FF }
}

/// Whether the code runs in the main executor's interrupt.
fn in_main() -> bool {
    active() == MAIN_EXCEPTION.load(Ordering::Relaxed)
}

/// Before a poll of the main executor, from its interrupt: no task timed yet.
pub(crate) fn poll_begins() {
    MAIN_EXCEPTION.store(active(), Ordering::Relaxed);
    LONGEST_US.store(0, Ordering::Relaxed);
    LONGEST_TASK.store(0, Ordering::Relaxed);
}

/// The longest task poll of the main executor's last poll: (µs, the task's address).
pub(crate) fn longest() -> (u32, u32) {
    (LONGEST_US.load(Ordering::Relaxed), LONGEST_TASK.load(Ordering::Relaxed))
}

#[unsafe(no_mangle)]
fn _embassy_trace_task_exec_begin(_executor_id: u32, task_id: u32) {
    if in_main() {
        TASK.store(task_id, Ordering::Relaxed);
        STARTED.store(crate::time::counter_us(), Ordering::Relaxed);
    }
}

#[unsafe(no_mangle)]
fn _embassy_trace_task_exec_end(_executor_id: u32, task_id: u32) {
    if in_main() && TASK.load(Ordering::Relaxed) == task_id {
        let took = crate::time::counter_us().wrapping_sub(STARTED.load(Ordering::Relaxed));
        if took > LONGEST_US.load(Ordering::Relaxed) {
            LONGEST_US.store(took, Ordering::Relaxed);
            LONGEST_TASK.store(task_id, Ordering::Relaxed);
        }
    }
}

#[unsafe(no_mangle)]
fn _embassy_trace_poll_start(_executor_id: u32) {}

#[unsafe(no_mangle)]
fn _embassy_trace_task_new(_executor_id: u32, _task_id: u32) {}

#[unsafe(no_mangle)]
fn _embassy_trace_task_end(_executor_id: u32, _task_id: u32) {}

#[unsafe(no_mangle)]
fn _embassy_trace_task_ready_begin(_executor_id: u32, _task_id: u32) {}

#[unsafe(no_mangle)]
fn _embassy_trace_executor_idle(_executor_id: u32) {}
