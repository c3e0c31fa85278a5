//! The QEMU board: ARM's MPS2 AN386 image as QEMU emulates it (`-M mps2-an386`): Cortex-M4F at
//! 25 MHz, SMSC LAN9118 Ethernet at 0x4020_0000 on IRQ 13, SysTick on the core clock. Only
//! this crate differs from the STM32 board; the application code is the same.
//!
//! - Executors (`executor`): Embassy's raw executors, the main one polled from an interrupt, the
//!   realtime one from another above it, the background one in thread mode on its own stack,
//!   in a loop that sleeps with WFI (the stock WFE loop never sleeps under QEMU and burns a host
//!   core).
//! - Time: the FPGAIO's counter, made to count microseconds (QEMU derives it from its virtual
//!   clock: no tick lost when the host is busy); SysTick at 1 kHz wakes embassy-time-queue-utils'
//!   queue.
//! - Network: the LAN9118 driver, interrupt-driven receive, with the MAC QEMU gives the NIC.
//!   QEMU's user network gives the guest 10.0.2.15/24 with gateway 10.0.2.2, used instead of
//!   the stored IP settings (the Modbus port still comes from the settings); on a TAP device
//!   (`scripts/qemu run MODEL --tap`, the `TAP` test switch) the stored settings, as on a LAN.
//! - Flash: regions of QEMU's writable code memory driven as NOR flash (`remodaq-ram-nor`):
//!   the settings, and the update and state partitions of the bootloader (`bootloader/`),
//!   which starts the application (layout.x).
//! - Logs are dropped (no RTT here); a panic prints over semihosting and ends QEMU.
#![no_std]
#![cfg(target_os = "none")]

pub mod analog;
pub mod digital;
pub mod executor;
pub mod flash;
mod irq;
mod probe;
mod time;
mod trace;

use core::sync::atomic::{AtomicBool, Ordering};

use cortex_m::peripheral::NVIC;
use embassy_executor::{SendSpawner, Spawner};
use embassy_net::{Ipv4Address, Ipv4Cidr, StackResources, StaticConfigV4};
use remodaq_lan9118::{Lan9118, Registers};
use remodaq_net::backlog::{Backlogged, GATES};
use remodaq_net::EmbassyNet;
use remodaq_shared::app::spawn;
use remodaq_shared::board::Effect;
use remodaq_shared::board::{Board, Effects};
use remodaq_shared::info;
use remodaq_shared::net::{mac_from_uid, NetConfig};
use static_cell::StaticCell;

/// The LAN9118's registers.
#[derive(Clone, Copy)]
pub struct Mmio;

const LAN9118_BASE: usize = 0x4020_0000;
const LAN9118_IRQ: u16 = 13;

impl Registers for Mmio {
    fn read(&self, offset: usize) -> u32 {
        // SAFETY: the LAN9118's register block is at LAN9118_BASE on this machine; offsets come
        // from the driver's register map (all inside the block), 32-bit aligned.
        unsafe { core::ptr::read_volatile((LAN9118_BASE + offset) as *const u32) }
    }
    fn write(&self, offset: usize, value: u32) {
        // SAFETY: as for `read`.
        unsafe { core::ptr::write_volatile((LAN9118_BASE + offset) as *mut u32, value) }
    }
}

extern "C" fn lan9118_interrupt() {
    probe::interrupted();
    remodaq_lan9118::on_interrupt(Mmio);
}

extern "C" fn unused_interrupt() {}

/// The device interrupt vectors (cortex-m-rt `device` feature): the LAN9118 on IRQ 13, the
/// realtime executor on [`executor::REALTIME_IRQ`].
#[unsafe(link_section = ".vector_table.interrupts")]
#[unsafe(no_mangle)]
static __INTERRUPTS: [extern "C" fn(); 32] = {
    let mut v: [extern "C" fn(); 32] = [unused_interrupt; 32];
    v[LAN9118_IRQ as usize] = lan9118_interrupt;
    v[executor::REALTIME_IRQ as usize] = executor::realtime_interrupt;
    v[executor::MAIN_IRQ as usize] = executor::main_interrupt;
    v
};

/// The Ethernet device of this board.
pub type Device = Lan9118<Mmio>;

/// The test switches (layout.x): words QEMU sets at every reset when the test command or
/// `scripts/qemu run --tap` starts the machine with `-device loader,addr=ADDR,data=VALUE,
/// data-len=4`; 0 otherwise. Each switch is one word and is on only with its exact value.
pub mod test_switches {
    /// At 0x003F_F000: every conversion of the 8318's front end fails (a broken or missing
    /// AD7124-8), in every image started on this machine: "FEND".
    pub const FRONT_END_FAULT: u32 = 0x4645_4E44;
    /// At 0x003F_F004: the NIC is on a TAP device, on a LAN of its own: the module takes its
    /// stored network settings (factory 192.168.0.1/24), as on a real LAN, instead of QEMU's
    /// user-network address: "TAP ".
    pub const TAP: u32 = 0x5441_5020;

    unsafe extern "C" {
        static __test_switches: [u32; 2];
    }

    fn word(n: usize) -> u32 {
        // SAFETY: words of QEMU's code memory that nothing in the firmware writes (layout.x);
        // volatile, aligned reads.
        unsafe { core::ptr::read_volatile(core::ptr::addr_of!(__test_switches[n])) }
    }

    /// The front-end fault switch.
    pub fn front_end_fault() -> bool {
        word(0) == FRONT_END_FAULT
    }

    /// The TAP switch.
    pub fn tap() -> bool {
        word(1) == TAP
    }
}

use remodaq_net::STACK_SOCKETS;

/// The MPS2 AN386 as QEMU emulates it.
pub struct QemuBoard {
    mac: [u8; 6],
    boot: Option<(flash::DfuFlash, flash::StateFlash)>,
}

impl Board for QemuBoard {
    type Flash = flash::SettingsFlash;
    const SETTINGS_SIZE: u32 = flash::SIZE as u32;
    /// QEMU's user network shows every client as its gateway, 10.0.2.2: one address for all.
    const CONNECTIONS_PER_SOURCE: usize = remodaq_shared::sockets::MODBUS_CONNECTIONS;
    type Net = EmbassyNet<QemuEffects>;
    type Dfu = flash::DfuFlash;
    type BootState = flash::StateFlash;
    /// The modules' I/O is simulated: nothing to reserve.
    type Resources = ();

    /// Starts the time driver.
    fn init(_spawner: Spawner) -> (Self, flash::SettingsFlash, ()) {
        stack::paint_stack();
        let Some(mut core) = cortex_m::Peripherals::take() else { panic!("init twice") };
        time::start(&mut core.SYST);
        let regions = flash::Regions::take();
        // The MAC the LAN9118 holds from its EEPROM (QEMU's `-nic ...,mac=`, so that two
        // modules on one LAN differ), or one of the board's own.
        let mac = remodaq_lan9118::stored_mac(Mmio).unwrap_or_else(|| mac_from_uid(b"qemu-mps2-an"));
        let board = QemuBoard { mac, boot: Some((regions.dfu, regions.state)) };
        (board, regions.settings, ())
    }

    /// The partitions the bootloader (`bootloader/`) swaps from.
    fn boot_partitions(&mut self) -> Option<(flash::DfuFlash, flash::StateFlash)> {
        self.boot.take()
    }

    /// The machine has no reset-cause register: a restart leaves a mark in RAM that a system
    /// reset keeps (QEMU reloads the image's sections, not the uninitialised RAM).
    fn reset_cause(&self) -> remodaq_shared::diagnostics::ResetCause {
        // SAFETY: read and cleared once, here, before anything else uses it; a volatile access
        // to a static the linker places in .uninit (not zeroed at start-up).
        let marked = unsafe {
            let marked = core::ptr::read_volatile(core::ptr::addr_of!(RESTART_MARK)) == RESTART_MAGIC;
            core::ptr::write_volatile(core::ptr::addr_of_mut!(RESTART_MARK), 0);
            marked
        };
        if marked {
            remodaq_shared::diagnostics::ResetCause::Software
        } else {
            remodaq_shared::diagnostics::ResetCause::PowerOn
        }
    }

    /// The words a restart left in RAM ([`RETAINED`]).
    fn retained(&mut self) -> Option<remodaq_shared::settings::Retained> {
        // SAFETY: read and cleared once, at start, before anything else uses it: volatile
        // accesses to a static the linker places in .uninit.
        let words = unsafe {
            let words = core::ptr::read_volatile(core::ptr::addr_of!(RETAINED));
            core::ptr::write_volatile(core::ptr::addr_of_mut!(RETAINED), [0; 4]);
            words
        };
        remodaq_shared::settings::Retained::from_words(words)
    }

    /// No button on this board.
    fn factory_reset_requested(&self) -> bool {
        false
    }

    fn mac(&self) -> [u8; 6] {
        self.mac
    }

    /// The machine has no entropy source: a fixed seed, which the module's generator stirs with
    /// the time (ms) and source of every request for a nonce. Nonces do not repeat in practice,
    /// but they are not unpredictable: a test board only (docs/security.md).
    fn entropy(&mut self) -> [u8; 32] {
        let mut seed = [0u8; 32];
        seed[..6].copy_from_slice(&self.mac);
        seed[6..].copy_from_slice(b"qemu-mps2-an386 no entropy");
        seed
    }

    /// Brings up the LAN9118 and the network stack: on QEMU's user network at 10.0.2.15/24,
    /// whatever the stored address (the Modbus port is the stored one); on a TAP device (the
    /// `TAP` test switch) at the stored settings.
    fn start_network(self, spawner: Spawner, stored: NetConfig) -> (EmbassyNet<QemuEffects>, NetConfig) {
        let device = match Lan9118::new(Mmio, self.mac) {
            Ok(device) => device,
            Err(e) => panic!("LAN9118: {:?}", defmt::Debug2Format(&e)),
        };
        // Test images only: a NIC whose link never comes up (the self-test must fail).
        #[cfg(feature = "test-link-down")]
        let device = {
            let mut device = device;
            device.hold_link_down();
            device
        };
        // SAFETY: the handler is in the vector table and touches only the driver's waker.
        unsafe { NVIC::unmask(irq::Irq(LAN9118_IRQ)) };
        // On a TAP device the stored settings, as on a real LAN; on QEMU's user network its
        // fixed guest address (the stored port still applies).
        let running = if test_switches::tap() {
            stored
        } else {
            NetConfig { ip: GUEST_IP, mask: [255, 255, 255, 0], gateway: GATEWAY, port: stored.port }
        };
        let gateway = (running.gateway != [0; 4]).then(|| Ipv4Address::from(running.gateway));
        let config = embassy_net::Config::ipv4_static(StaticConfigV4 {
            address: Ipv4Cidr::new(Ipv4Address::from(running.ip), running.prefix_len().unwrap_or(24)),
            gateway,
            dns_servers: heapless::Vec::new(),
        });
        // Only intact SYNs to this MAC and address wait in the backlog. On the user network every
        // client comes from QEMU's gateway (10.0.2.2), so one source may fill it.
        let held =
            if test_switches::tap() { remodaq_net::backlog::HELD_PER_SOURCE } else { remodaq_net::backlog::HELD };
        remodaq_net::backlog::identify(self.mac, running.ip, held);
        static RESOURCES: StaticCell<StackResources<STACK_SOCKETS>> = StaticCell::new();
        // No entropy on this machine: a fixed key for the keyed ISNs (remodaq_net::isn), as the
        // stack's fixed seed; a test board only (docs/security.md).
        let (stack, runner) = embassy_net::new(
            Backlogged::new(probe::Probed::new(device, stored.port), GATES, *b"qemu: no entropy"),
            config,
            RESOURCES.init(StackResources::new()),
            0x5EED_8300,
        );
        // The runner (7 KB: the LAN9118 driver's frames and smoltcp's interface) in a static of
        // its own, the task given a reference: moved into the task's pool, it was copied
        // through the start-up's stack once more, 6.4 KB at the start-up's deepest (issue #40,
        // docs/design.md "Three executors").
        static RUNNER: StaticCell<embassy_net::Runner<'static, Backlogged<probe::Probed<Device>>>> = StaticCell::new();
        spawn(spawner, net_task(RUNNER.init(runner)), "net");
        spawn(spawner, stack_task(), "stack");
        info!("network: {}.{}.{}.{}", running.ip[0], running.ip[1], running.ip[2], running.ip[3]);
        (EmbassyNet { stack, port: stored.port, effects: QemuEffects }, running)
    }

    /// No watchdog on this board.
    fn app_alive() {}

    fn realtime(_: Spawner) -> SendSpawner {
        executor::realtime()
    }
}

/// Left in RAM by a restart, for the next start's reset cause.
#[unsafe(link_section = ".uninit.RESTART_MARK")]
static mut RESTART_MARK: u32 = 0;
const RESTART_MAGIC: u32 = 0x5245_5354;

/// Left in RAM by a restart: the flash commit budgets' debts
/// (`remodaq_shared::settings::Retained`), which a system reset keeps as it keeps
/// [`RESTART_MARK`].
#[unsafe(link_section = ".uninit.RETAINED")]
static mut RETAINED: [u32; 4] = [0; 4];

/// Discovery's effects here: identify is a log line, restart a system reset.
pub struct QemuEffects;

impl Effects for QemuEffects {
    async fn apply(&self, effect: Effect) {
        match effect {
            Effect::None => {}
            Effect::Identify => info!("identify"),
            Effect::Restart => {
                embassy_time::Timer::after_millis(300).await;
                let words = remodaq_shared::settings::Retained::now().to_words();
                // SAFETY: volatile writes to statics only this and `reset_cause` / `retained`
                // touch.
                unsafe {
                    core::ptr::write_volatile(core::ptr::addr_of_mut!(RESTART_MARK), RESTART_MAGIC);
                    core::ptr::write_volatile(core::ptr::addr_of_mut!(RETAINED), words);
                }
                cortex_m::peripheral::SCB::sys_reset();
            }
        }
    }
}

const GUEST_IP: [u8; 4] = [10, 0, 2, 15];
const GATEWAY: [u8; 4] = [10, 0, 2, 2];

#[embassy_executor::task]
async fn net_task(runner: &'static mut embassy_net::Runner<'static, Backlogged<probe::Probed<Device>>>) -> ! {
    runner.run().await
}

/// The stack's high-water mark ([`stack`]), in QEMU's log each time it rose by 256 bytes or
/// more (looked at every second), where `tools/qemu-e2e` reads it back (issue #39). On the main
/// executor, so the scan never delays the I/O loop; a line in the log is a semihosting call,
/// which stops the machine for a few ms: only when the mark rises.
#[embassy_executor::task]
async fn stack_task() -> ! {
    let (mut said, mut background_said) = (0, 0);
    loop {
        embassy_time::Timer::after_secs(1).await;
        let (bottom, top) = stack::main_stack();
        let (used, size) = (high_water_stepwise(bottom, top).await, top - bottom);
        if used >= said + 256 {
            said = used;
            cortex_m_semihosting::hprintln!("qemu board: stack high-water mark {} of {} bytes", used, size);
        }
        let (bottom, top) = executor::background_stack();
        let used = high_water_stepwise(bottom, top).await;
        if used >= background_said + 256 {
            background_said = used;
            cortex_m_semihosting::hprintln!(
                "qemu board: the background executor's stack used {} of {} bytes at the most",
                used,
                top - bottom
            );
        }
    }
}

/// [`stack::high_water`] of a painted stack (the main one, or the background executor's,
/// painted by `executor::run`), 2 KB a poll: the whole scan, 50 KB of paint read one word at a
/// time, held the main executor 0.7 ms under QEMU each second, which a Modbus request measured
/// then waited behind (`probe`).
async fn high_water_stepwise(bottom: usize, top: usize) -> usize {
    const STEP: usize = 2048;
    let mut at = bottom;
    while at < top {
        let end = (at + STEP).min(top);
        // SAFETY: `at..end` lies in the stack `bottom..top`, word-aligned (the callers' stacks).
        let used = unsafe { stack::high_water(at, end) };
        if used > 0 {
            return top - (end - used);
        }
        at = end;
        embassy_futures::yield_now().await;
    }
    0
}

pub mod stack;

/// Logs go nowhere on this board (defmt needs a logger to link).
#[defmt::global_logger]
struct NoLogger;

// SAFETY: the logger keeps no state; every function does nothing.
unsafe impl defmt::Logger for NoLogger {
    fn acquire() {}
    unsafe fn flush() {}
    unsafe fn release() {}
    unsafe fn write(_bytes: &[u8]) {}
}

static PANICKED: AtomicBool = AtomicBool::new(false);

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    if !PANICKED.swap(true, Ordering::Relaxed) {
        cortex_m_semihosting::hprintln!("panic: {}", info);
    }
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}
