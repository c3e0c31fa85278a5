//! embassy-time on the MPS2 FPGAIO's counter, with the timer queue checked at each SysTick.
//!
//! The time is the FPGAIO's COUNTER register (base 0x4002_8000, offset 0x18), made to count
//! microseconds by PRESCALE = 24 on its 25 MHz prescale clock (AN385/AN386 application
//! notes, "FPGA system control and I/O"; QEMU `hw/arm/mps2.c` sets `prescale-clk` to 25 MHz and
//! `hw/misc/mps2-fpgaio.c` computes COUNTER from its virtual clock). Counting SysTick
//! interrupts instead loses every tick QEMU coalesces while its host thread is descheduled, and
//! the guest's clock then lags the wall clock (0.3 % was seen under a build): the 8350's
//! simulated inputs, which follow the guest's clock, then gave fewer edges than the seconds
//! that passed. Microseconds, as on the STM32 (embassy-time's `tick-hz-1_000_000`): with a 1 ms
//! time base a deadline 500 ms after an event fell up to 1 ms early in wall-clock terms (the
//! event's instant rounded down), which the 8350's host-watchdog check saw as a trip 499.8 ms
//! after its arming write. SysTick, at 1 kHz from the 25 MHz core clock, only wakes the timer
//! queue (timers wake within 1 ms).
//!
//! The board's critical sections (the `critical-section` crate's implementation for the whole
//! image) mask interrupts as cortex-m's single-core one does, and time each outermost one on
//! the same counter: SysTick says in QEMU's log how much of a stall of the machine a critical
//! section of the firmware held, so that a test never takes the firmware's own masked time
//! for this PC's (tools/qemu-e2e).

use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicU32, Ordering};
use core::task::Waker;

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::exception;
use critical_section::{Mutex, RawRestoreState};
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

const CORE_HZ: u32 = 25_000_000;
/// The SysTick interrupt's rate: the timer queue is checked this often.
const SYSTICK_HZ: u32 = 1_000;
/// The time base's rate (embassy-time's tick rate).
const TICK_HZ: u32 = 1_000_000;

/// The FPGAIO's registers.
const FPGAIO: usize = 0x4002_8000;
const COUNTER: usize = FPGAIO + 0x18;
const PRESCALE: usize = FPGAIO + 0x1C;
const PSCNTR: usize = FPGAIO + 0x20;
/// The FPGAIO's prescale clock.
const PRESCALE_CLK_HZ: u32 = 25_000_000;

fn fpgaio_read(register: usize) -> u32 {
    // SAFETY: a register of the FPGAIO block this machine maps at FPGAIO; aligned, volatile.
    unsafe { core::ptr::read_volatile(register as *const u32) }
}

fn fpgaio_write(register: usize, value: u32) {
    // SAFETY: as for `fpgaio_read`; only `start` writes the counter's registers.
    unsafe { core::ptr::write_volatile(register as *mut u32, value) }
}

struct SysTickDriver {
    /// The last COUNTER value read, and the high bits of the time (its wraps, every 71.6 minutes at 1 MHz).
    epoch: Mutex<Cell<(u32, u64)>>,
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: SysTickDriver = SysTickDriver {
    epoch: Mutex::new(Cell::new((0, 0))),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

impl Driver for SysTickDriver {
    /// Microseconds since the start, from the FPGAIO's counter; read at every SysTick, so a
    /// wrap of its 32 bits (every 71 minutes) is never missed.
    fn now(&self) -> u64 {
        critical_section::with(|cs| {
            let epoch = self.epoch.borrow(cs);
            let (last, mut high) = epoch.get();
            let counter = fpgaio_read(COUNTER);
            if counter < last {
                high += 1 << 32;
            }
            epoch.set((counter, high));
            high | u64::from(counter)
        })
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        let now = self.now();
        critical_section::with(|cs| {
            let mut queue = self.queue.borrow(cs).borrow_mut();
            if queue.schedule_wake(at, waker) {
                // Wake anything already due; the rest is checked at each tick.
                queue.next_expiration(now);
            }
        });
    }
}

/// Starts the microsecond counter and the 1 kHz tick.
pub fn start(syst: &mut SYST) {
    let per_tick = PRESCALE_CLK_HZ / TICK_HZ - 1;
    fpgaio_write(PRESCALE, per_tick);
    fpgaio_write(PSCNTR, per_tick);
    fpgaio_write(COUNTER, 0);
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(CORE_HZ / SYSTICK_HZ - 1);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
}

/// The firmware's critical sections, measured: interrupts masked by PRIMASK as in cortex-m's
/// `critical-section-single-core` (which this board does not enable), and each outermost
/// section (PRIMASK clear before it) timed on the FPGAIO's microsecond counter. Nothing can
/// interrupt an outermost section (PRIMASK masks every interrupt and SysTick), so one start
/// time serves. The cost: two reads of the counter per outermost section.
struct MeasuredCriticalSection;
critical_section::set_impl!(MeasuredCriticalSection);

/// The counter when the outermost critical section under way began.
static ENTERED_AT: AtomicU32 = AtomicU32::new(0);
/// Time spent in critical sections since the last SysTick, µs.
static MASKED_US: AtomicU32 = AtomicU32::new(0);
/// The longest critical section since the last SysTick, µs.
static LONGEST_US: AtomicU32 = AtomicU32::new(0);

// SAFETY: a single-core machine: masking interrupts excludes every other context (as
// cortex-m's implementation); `release` restores the PRIMASK that `acquire` found.
unsafe impl critical_section::Impl for MeasuredCriticalSection {
    unsafe fn acquire() -> RawRestoreState {
        let primask = cortex_m::register::primask::read_raw();
        cortex_m::interrupt::disable();
        if primask & 1 == 0 {
            ENTERED_AT.store(fpgaio_read(COUNTER), Ordering::Relaxed);
        }
        primask
    }

    unsafe fn release(primask: RawRestoreState) {
        if primask & 1 == 0 {
            // Interrupts are still masked: plain loads and stores suffice.
            let held = fpgaio_read(COUNTER).wrapping_sub(ENTERED_AT.load(Ordering::Relaxed));
            MASKED_US.store(MASKED_US.load(Ordering::Relaxed).saturating_add(held), Ordering::Relaxed);
            if held > LONGEST_US.load(Ordering::Relaxed) {
                LONGEST_US.store(held, Ordering::Relaxed);
            }
        }
        // SAFETY: the PRIMASK `acquire` found: interrupts enabled again only if they were then.
        unsafe { cortex_m::register::primask::write_raw(primask) };
    }
}

/// A gap between two SysTicks longer than this is a stall: SysTick preempts every task, so
/// only a critical section (interrupts masked) or QEMU's thread put aside by the PC (during
/// which the guest's clock, the wall clock, ran on) delays it. The log says how much of the
/// gap critical sections held, measured above: that part is the firmware's, the rest this
/// PC's. 5 ms: less than the 8350 output ring's 6.4 ms slack, and rare enough that the log's
/// semihosting writes (each one stops the machine) do not disturb the latency checks (a 2 ms
/// threshold logged hundreds a session on a loaded PC).
const STALL_US: u64 = 5_000;

/// A critical section at least this long is said in the log when it is the longest yet.
const LONG_SECTION_US: u32 = 1_000;

/// A task poll of the main executor at least this long is said in the log, each one: it delays
/// every other task of the executor by as much (MQTT's TLS handshake's arithmetic held it 20-400
/// ms before it ran on the background executor: docs/mqtt.md "Never in the way"). A poll of the
/// executor itself runs every ready task, and those they wake, in turn
/// (`remodaq_shared::app::Priority`): its length says nothing of how long any one task held
/// the others. 3 ms: rare in normal running, so that the
/// log's writes (each one stops the machine) do not disturb the latency checks.
const LONG_POLL_US: u32 = 3_000;

/// The FPGAIO's microsecond counter (wraps every 71 minutes: subtract with `wrapping_sub`).
pub(crate) fn counter_us() -> u32 {
    fpgaio_read(COUNTER)
}

/// After a poll of the main executor whose longest task poll took `longest` µs: said in the log
/// if long ([`LONG_POLL_US`]), with the task's address (`crate::trace::longest`), at the
/// executor poll's end. The time includes what preempted the task (interrupts, the realtime
/// executor) and any stall of the machine by this PC, which the log's stall lines say.
pub(crate) fn main_poll((longest, task): (u32, u32)) {
    if (LONG_POLL_US..1 << 31).contains(&longest) {
        cortex_m_semihosting::hprintln!(
            "qemu board: a task poll of the main executor took {} us, at {} us; the task at {:#010x}",
            longest,
            DRIVER.now(),
            task
        );
    }
}

/// A poll of the background executor that took `took` µs (with what preempted it: the main
/// executor among the rest): said in the log if long ([`LONG_POLL_US`]), so that a test can tell
/// when its work (MQTT's TLS handshake) ran and what the main executor did meanwhile.
pub(crate) fn background_poll(took: u32) {
    if (LONG_POLL_US..1 << 31).contains(&took) {
        cortex_m_semihosting::hprintln!(
            "qemu board: a poll of the background executor took {} us, at {} us",
            took,
            DRIVER.now()
        );
    }
}

/// The time of the last SysTick, µs.
static LAST_TICK_US: Mutex<Cell<u64>> = Mutex::new(Cell::new(0));
/// The longest critical section said in the log so far, µs.
static LONGEST_SAID_US: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    let now = DRIVER.now();
    let (last, masked, longest) = critical_section::with(|cs| {
        DRIVER.queue.borrow(cs).borrow_mut().next_expiration(now);
        let masked = MASKED_US.load(Ordering::Relaxed);
        let longest = LONGEST_US.load(Ordering::Relaxed);
        MASKED_US.store(0, Ordering::Relaxed);
        LONGEST_US.store(0, Ordering::Relaxed);
        (LAST_TICK_US.borrow(cs).replace(now), masked, longest)
    });
    // Nothing before the first tick counts: the counter ran at another rate before `start`.
    if last == 0 {
        return;
    }
    // Said in QEMU's log, so a test can tell a stall of the PC from a late task of the firmware
    // (tools/qemu-e2e: the 8350's output ring during an update, Modbus during a web load), and
    // see the firmware's longest critical sections.
    if now.saturating_sub(last) > STALL_US {
        cortex_m_semihosting::hprintln!(
            "qemu board: the machine stalled {} us, at {} us; critical sections {} us, the longest {} us",
            now - last,
            now,
            masked,
            longest
        );
    }
    if longest >= LONG_SECTION_US && longest > LONGEST_SAID_US.load(Ordering::Relaxed) {
        LONGEST_SAID_US.store(longest, Ordering::Relaxed);
        cortex_m_semihosting::hprintln!("qemu board: critical section {} us, the longest yet, at {} us", longest, now);
    }
}
