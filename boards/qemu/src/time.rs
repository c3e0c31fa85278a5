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

use core::cell::{Cell, RefCell};
use core::task::Waker;

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::exception;
use critical_section::Mutex;
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

/// A gap between two SysTicks longer than this is the machine stalled: SysTick preempts every
/// task (only a critical section as long would delay it: the firmware's are bounded far below,
/// docs/design.md), so a longer gap is QEMU's thread put aside by the PC, during which the
/// guest's clock, the wall clock, ran on. 5 ms: less than the 8350 output ring's 6.4 ms slack,
/// and rare enough that the log's semihosting writes (each one stops the machine) do not
/// disturb the latency checks (a 2 ms threshold logged hundreds a session on a loaded PC).
const STALL_US: u64 = 5_000;

/// The time of the last SysTick, µs.
static LAST_TICK_US: Mutex<Cell<u64>> = Mutex::new(Cell::new(0));

#[exception]
fn SysTick() {
    let now = DRIVER.now();
    let last = critical_section::with(|cs| {
        DRIVER.queue.borrow(cs).borrow_mut().next_expiration(now);
        LAST_TICK_US.borrow(cs).replace(now)
    });
    // Said in QEMU's log, so a test can tell a stall of the PC from a late task of the firmware
    // (tools/qemu-e2e: the 8350's output ring during an update).
    if last != 0 && now.saturating_sub(last) > STALL_US {
        cortex_m_semihosting::hprintln!("qemu board: the machine stalled {} us, at {} us", now - last, now);
    }
}
