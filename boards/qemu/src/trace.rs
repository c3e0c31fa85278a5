//! embassy-executor's trace hooks (its feature `trace`, turned on by this board alone): which
//! task a long poll of the main executor spent its time in. The board's log names the task by
//! its address (`llvm-nm -C` of the image gives the pool it lies in), beside the poll's length
//! (`crate::time::main_poll`): what to split when Modbus waits behind a task (issue #40, the
//! worst latency under QEMU). Only the main executor's tasks are timed: their hooks run in its
//! interrupt ([`crate::executor::MAIN_IRQ`]), told from the others' by the active exception.

use core::sync::atomic::{AtomicU32, Ordering};

/// When the task being polled began (µs, the board's counter), and which.
static STARTED: AtomicU32 = AtomicU32::new(0);
static TASK: AtomicU32 = AtomicU32::new(0);
/// The longest task poll of the current executor poll: its length (µs) and its task.
static LONGEST_US: AtomicU32 = AtomicU32::new(0);
static LONGEST_TASK: AtomicU32 = AtomicU32::new(0);

/// Whether the code runs in the main executor's interrupt (SCB ICSR VECTACTIVE, ARMv7-M ARM
/// B3.2.4: exception number 16 + the IRQ).
fn in_main() -> bool {
    matches!(
        cortex_m::peripheral::SCB::vect_active(),
        cortex_m::peripheral::scb::VectActive::Interrupt { irqn } if u16::from(irqn) == crate::executor::MAIN_IRQ
    )
}

/// Before a poll of the main executor: no task timed yet.
pub(crate) fn poll_begins() {
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
