//! The board's three executors, by priority (docs/design.md, "Three executors"):
//! - the realtime one ([`crate::Stm32Board`]'s `Board::realtime`: UART4's interrupt at priority
//!   8), the 8350's I/O loop;
//! - the main one, polled from UART5's interrupt at the lowest priority ([`MAIN_PRIORITY`]): the
//!   network, the services, the 8318's acquisition; every other interrupt preempts it;
//! - the background one, embassy's thread-mode executor (WFE between polls), below every
//!   interrupt: work every other task preempts, MQTT's service with its TLS (`remodaq_mqtt::link`,
//!   docs/mqtt.md "Never in the way"), whose P-256 arithmetic would otherwise hold the main
//!   executor for tens of ms, and the services' offload worker.
//!
//! Neither UART4 nor UART5 is used on this board, so only the executors' pender requests their
//! interrupts (NVIC STIR, PM0214 §4.3.8; embassy-executor 0.10 `platform/cortex_m.rs`, whose
//! `__pender` sends a thread-mode wake as SEV and an interrupt executor's as a software
//! request of its interrupt). The F429 implements 4 priority bits (PM0214 §4.3.7), all of them
//! preemption bits (PRIGROUP at its reset value, §4.4.5, which neither embassy-stm32 0.6 nor
//! cortex-m-rt changes): 0 the most urgent, 15 the least. embassy-stm32 0.6 leaves the drivers'
//! interrupts (Ethernet, DMA, the flash, the RNG, TIM2's time driver) at 0, and must: the board's
//! `init`, on the main executor, waits with `embassy_time::block_for` (the PHY's reset, up to
//! 3.2 s), whose time moves only while TIM2's overflow handler preempts it. No driver here may
//! bind UART4 or UART5 (`bind_interrupts!` would clash with these handlers: a link error).
//!
//! One stack for all (the main stack, MSP): thread mode and every handler run on it (ARMv7-M
//! ARM B1.4.4: CONTROL.SPSEL is left 0), so MQTT's deepest calls (TLS's handshake) add to those of
//! whatever preempts it. The memory plan's 32 KiB holds both (docs/mqtt.md, "Sizes":
//! `qemu-e2e` holds the main stack's high-water mark plus the background's to it).

use embassy_executor::{Executor, InterruptExecutor, SendSpawner, Spawner};
use embassy_stm32::interrupt;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use static_cell::StaticCell;

/// The main executor's priority: the least urgent (below the realtime executor's 8 and the
/// drivers' 0), above thread mode only.
pub const MAIN_PRIORITY: Priority = Priority::P15;

/// The main executor ([`run`]).
static MAIN: InterruptExecutor = InterruptExecutor::new();

#[interrupt]
#[allow(non_snake_case)]
unsafe fn UART5() {
    // SAFETY: the executor's interrupt handler, its only caller; `start` ran before the
    // interrupt was unmasked.
    unsafe { MAIN.on_interrupt() }
}

/// Starts the main executor, hands `init` the background executor's spawner and the main one's,
/// then runs the background executor in thread mode, forever. What `init` spawns on the main
/// executor may start before `init` returns (its interrupt preempts thread mode).
pub fn run(init: impl FnOnce(Spawner, SendSpawner)) -> ! {
    static BACKGROUND: StaticCell<Executor> = StaticCell::new();
    // Its priority set before `start`, which unmasks it (embassy-executor 0.10
    // `InterruptExecutor::start`): NVIC_IPR of UART5 (PM0214 §4.3.7).
    interrupt::UART5.set_priority(MAIN_PRIORITY);
    let main = MAIN.start(interrupt::UART5);
    BACKGROUND.init(Executor::new()).run(|background| init(background, main))
}
