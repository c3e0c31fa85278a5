//! The STM32 board: the Nucleo-F429ZI reference hardware (STM32F429ZI, LAN8742A RMII PHY).
//! Every pin, clock and peripheral choice of the firmware is made here and nowhere else; a port
//! to the RemoDAQ PCB changes this crate only.
#![no_std]
#![cfg(target_os = "none")]

pub mod analog;
mod ccm;
pub mod executor;
pub mod x32;
/// The painted stack (boards/stack.rs): its high-water mark for the on-target check.
pub mod stack {
    include!("../../stack.rs");
}
pub mod digital;
pub mod phy;
pub mod resources;

use defmt_rtt as _;
use panic_probe as _;

use embassy_executor::{InterruptExecutor, SendSpawner, Spawner};
use embassy_net::{Ipv4Address, Ipv4Cidr, StackResources, StaticConfigV4};
use embassy_stm32::eth::{Ethernet, PacketQueue, Sma};
use embassy_stm32::flash::{Async, Bank2Region1, Bank2Region2, Bank2Region3, Flash};
use embassy_stm32::gpio::{Flex, Input, Level, Output, Pull, Speed};
use embassy_stm32::peripherals::{ETH, ETH_SMA, IWDG};
use embassy_stm32::rng::Rng;
use embassy_stm32::time::Hertz;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, eth, flash, interrupt, peripherals, rng, Config};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer};
use remodaq_net::backlog::{Backlogged, GATES};
use remodaq_net::EmbassyNet;
use remodaq_shared::app::spawn;
use remodaq_shared::board::Effect;
use remodaq_shared::board::{Board, Effects};
use remodaq_shared::flash::{Serialized, CONTROLLER};
use remodaq_shared::health::{self, Heartbeat};
use remodaq_shared::net::{mac_from_uid, NetConfig};
use remodaq_shared::{error, info};
use static_cell::{ConstStaticCell, StaticCell};
use x32::X32;

pub use resources::Io;

bind_interrupts!(struct Irqs {
    ETH => eth::InterruptHandler;
    HASH_RNG => rng::InterruptHandler<peripherals::RNG>;
    FLASH => flash::InterruptHandler;
});

/// The Ethernet device of this board.
pub type Device = Ethernet<'static, ETH, phy::Lan8742a<Sma<'static, ETH_SMA>>>;
/// The settings flash: bank 2, sectors 12-15 (16 KiB each, 0x0810_0000), see `memory.x`.
/// Every flash partition of the board goes through [`Serialized`]: one operation, or one
/// sector's erase, at a time on the controller (docs/design.md, "Flash").
pub type SettingsFlash = Serialized<X32<Bank2Region1<'static, Async>>>;
/// The update partition (DFU): bank 2 sectors 17-23 (128 KiB each, 0x0812_0000), all of the
/// region, see `memory.x`.
pub type DfuFlash = Serialized<X32<Bank2Region3<'static, Async>>>;
/// The bootloader's state: bank 2 sector 16 (0x0811_0000, 64 KiB), all of bank 2 region 2.
/// Not in bank 1: marking an update (or a boot) erases the state, and while a sector erases
/// nothing can be read from its bank (RM0090 §3.6), so an erase in bank 1, where the code and
/// the vector table are, would stall the CPU and every interrupt for up to 0.8 s (a 16 KiB
/// sector at x8, 0.5 s at the x32 the board erases at: [`x32`]). Bank 1 is read on meanwhile
/// (read-while-write between the banks, §3.6).
pub type BootStateFlash = Serialized<X32<Bank2Region2<'static, Async>>>;

use remodaq_net::STACK_SOCKETS;
// The watchdog's period (`WATCHDOG_TIMEOUT_US`, 5.4 s at the least), shared with the
// bootloader. Fed every [`FEED_EVERY`] while every watched task beat within [`ALIVE_WINDOW`]; the
// worst case before a feed is then the window plus one feed interval, 3.5 s, under the 5.4 s
// minimum.
include!("../watchdog.rs");
const FEED_EVERY: Duration = Duration::from_millis(500);
/// How late a watched task may be. Neither watched task (network runner, application) waits
/// for the flash: settings commits run in the Modbus, discovery and update tasks, and hold the
/// register map only to copy settings in (docs/design.md, "Locks"); every erase is in bank 2,
/// so none stalls the CPU. The window is wide margin over a busy executor's latency.
const ALIVE_WINDOW: Duration = Duration::from_millis(3000);
/// Fed unconditionally this long after start-up while the tasks start (opening the settings
/// store may repair it, erasing a sector).
const START_GRACE: Duration = Duration::from_secs(20);

/// Liveness of the watched tasks (network, application), read by the watchdog task.
pub static HEARTBEAT: Heartbeat = Heartbeat::new(health::NET | health::APP);
/// Raised to blink the identify LED.
static IDENTIFY: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// The Nucleo-F429ZI.
pub struct Stm32Board {
    mac: [u8; 6],
    /// The USER button (B1, PC13) was held at power-up: reset every setting to its factory
    /// default (the documented way back when the password is lost).
    factory_reset: bool,
    eth: Device,
    seed: u64,
    /// The key of the keyed TCP initial sequence numbers (RFC 6528, remodaq_net::isn), from the RNG.
    isn_key: [u8; 16],
    /// 32 bytes of the RNG (RM0090 §24) for the module's random numbers (nonces, keys).
    entropy: [u8; 32],
    led: Output<'static>,
    reset_cause: remodaq_shared::diagnostics::ResetCause,
    boot: Option<(DfuFlash, BootStateFlash)>,
}

/// Whether PA12 is held as embassy's bank-2 reads need it on silicon before revision 3
/// (output, pull-down, low), read back from GPIOA's MODER, PUPDR and ODR (RM0090 §8.4): the
/// on-target check that the hold outlives `start_network` (stm32 review D1).
pub fn pa12_held() -> bool {
    use embassy_stm32::pac::gpio::vals::{Moder, Odr, Pupdr};
    use embassy_stm32::pac::GPIOA;
    const PIN: usize = 12;
    GPIOA.moder().read().moder(PIN) == Moder::OUTPUT
        && GPIOA.pupdr().read().pupdr(PIN) == Pupdr::PULL_DOWN
        && GPIOA.odr().read().odr(PIN) == Odr::LOW
}

/// Clocks at 180 MHz from the ST-LINK's 8 MHz MCO (HSE bypass), the flash caches, the
/// watchdog, then the peripherals.
fn init(spawner: Spawner) -> (Stm32Board, SettingsFlash, Io) {
    // First: the free stack painted (its high-water mark, issue #39), the CCM's statics
    // (memory.x `.ccmdata`, `.ccmbss`) given their initial values.
    stack::paint_stack();
    ccm::load();
    let mut config = Config::default();
    {
        use embassy_stm32::rcc::*;
        config.rcc.hse = Some(Hse { freq: Hertz(8_000_000), mode: HseMode::Bypass });
        config.rcc.pll_src = PllSource::HSE;
        config.rcc.pll = Some(Pll {
            prediv: PllPreDiv::DIV4,
            mul: PllMul::MUL180,
            divp: Some(PllPDiv::DIV2), // 180 MHz
            // PLL48CLK, the RNG's clock (RM0090 §6.3.2: PLLQ 0 and 1 are invalid; §24.3.1).
            // 360 MHz VCO / 8 = 45 MHz; 48 MHz would need SYSCLK 168 MHz, and only USB needs
            // exactly 48. The RNG wants it above HCLK / 16 (11.25 MHz) and at most 48 MHz.
            divq: Some(PllQDiv::DIV8),
            divr: None,
        });
        config.rcc.ahb_pre = AHBPrescaler::DIV1;
        config.rcc.apb1_pre = APBPrescaler::DIV4;
        config.rcc.apb2_pre = APBPrescaler::DIV2;
        config.rcc.sys = Sysclk::PLL1_P;
    }
    let p = embassy_stm32::init(config);
    // Why the MCU started (RM0090 §6.3.21 RCC_CSR of the F42x/F43x), before anything clears the flags.
    let reset_cause = reset_cause();
    // Freeze the IWDG while the debugger halts the core (RM0090 §38.16.4, DBG_IWDG_STOP), so
    // stepping through code with probe-rs does not reset the board.
    embassy_stm32::pac::DBGMCU.apb1fzr().modify(|w| w.set_iwdg(true));
    // The watchdog runs from here (RM0090 §21.3: started by writing 0xCCCC to IWDG_KR, which
    // `unleash` does; only a reset stops it), before anything that could wait for ever: the
    // Ethernet set-up spins on ETH_DMABMR SR, which never clears without the PHY's 50 MHz
    // REF_CLK (embassy-stm32 0.6 `eth/v1/mod.rs`, unbounded), and the PHY scan takes up to
    // 3.2 s when no PHY answers. A board that hangs there is reset (and a new image that does
    // is reverted by the bootloader), instead of hanging unguarded. It is fed here until the
    // watchdog task takes it over.
    let mut wdg = IndependentWatchdog::new(p.IWDG, WATCHDOG_TIMEOUT_US);
    wdg.unleash();
    // The flash accelerator (RM0090 §3.5.2, FLASH_ACR): embassy's clock set-up writes ACR with
    // the wait states only, leaving prefetch and both caches off. Reset the caches, then
    // enable them with prefetch: code runs from flash at 5 wait states otherwise.
    embassy_stm32::pac::FLASH.acr().modify(|w| {
        w.set_icrst(true);
        w.set_dcrst(true);
    });
    embassy_stm32::pac::FLASH.acr().modify(|w| {
        w.set_icrst(false);
        w.set_dcrst(false);
        w.set_prften(true);
        w.set_icen(true);
        w.set_dcen(true);
    });
    // PA12 held as an output, pulled down, low, for the program's life: embassy-stm32 0.6
    // refuses (panics on) bank-2 flash reads on silicon before revision 3 (REV_ID < 0x2001,
    // errata ES0206 2.2.11) unless it finds PA12 so (`flash/f4.rs`). PA12 is the Nucleo's USB
    // OTG FS D+, unused here. In a static: a `Flex` dropped returns its pin to analog (embassy
    // `gpio.rs`, `impl Drop for Flex`), which a field of the board did when `start_network`
    // took the board apart (stm32 review D1).
    static PA12: StaticCell<Flex<'static>> = StaticCell::new();
    let pa12 = PA12.init(Flex::new(p.PA12));
    pa12.set_low();
    pa12.set_as_input_output_pull(Speed::Low, Pull::Down);

    let mut rng = Rng::new(p.RNG, Irqs);
    let mut seed = [0u8; 8];
    rng.fill_bytes(&mut seed);
    let mut isn_key = [0u8; 16];
    rng.fill_bytes(&mut isn_key);
    let mut entropy = [0u8; 32];
    rng.fill_bytes(&mut entropy);

    let mac = mac_from_uid(&embassy_stm32::uid::uid());

    // Built in place (a ConstStaticCell: no 12-18 KB copy through the stack). 8 receive
    // descriptors: 8 Modbus clients and broadcasts may arrive at once.
    // The Ethernet DMA's descriptors and buffers: in SRAM, checked at link time (memory.x).
    #[unsafe(export_name = "REMODAQ_DMA_ETH")]
    static PACKETS: ConstStaticCell<PacketQueue<4, 8>> = ConstStaticCell::new(PacketQueue::new());
    // Nucleo-F429ZI RMII: REF_CLK PA1, MDIO PA2, MDC PC1, CRS_DV PA7, RXD0 PC4, RXD1 PC5,
    // TX_EN PG11, TXD0 PG13, TXD1 PB13.
    wdg.pet();
    let eth = Ethernet::new_with_phy(
        PACKETS.take(),
        p.ETH,
        Irqs,
        p.PA1,
        p.PA7,
        p.PC4,
        p.PC5,
        p.PG13,
        p.PB13,
        p.PG11,
        mac,
        phy::Lan8742a::new(Sma::new(p.ETH_SMA, p.PA2, p.PC1)),
    );

    wdg.pet();
    spawn(spawner, watchdog_task(wdg), "watchdog");

    let regions = Flash::new(p.FLASH, Irqs).into_regions();
    let settings_flash = Serialized::new(X32(regions.bank2_region1), &CONTROLLER);
    let boot = Some((
        Serialized::new(X32(regions.bank2_region3), &CONTROLLER),
        Serialized::new(X32(regions.bank2_region2), &CONTROLLER),
    ));
    // LD1 (green, PB0): the "identify" LED.
    let led = Output::new(p.PB0, Level::Low, Speed::Low);
    let factory_reset = Input::new(p.PC13, Pull::Down).is_high();

    let io = Io {
        analog: resources::AnalogPeripherals {
            spi: p.SPI1,
            sck: p.PB3,
            miso: p.PB4,
            mosi: p.PB5,
            cs: p.PD14,
            tx_dma: p.DMA2_CH3,
            rx_dma: p.DMA2_CH2,
            adc: p.ADC1,
            ntc: p.PA3,
        },
        digital: resources::DigitalPeripherals {
            tim_in: p.TIM1,
            tim_out: p.TIM8,
            dma_in: p.DMA2_CH5,
            dma_out: p.DMA2_CH1,
            di: [
                p.PE2.into(),
                p.PE3.into(),
                p.PE4.into(),
                p.PE5.into(),
                p.PE6.into(),
                p.PE7.into(),
                p.PE8.into(),
                p.PE9.into(),
                p.PE10.into(),
                p.PE11.into(),
                p.PE12.into(),
                p.PE13.into(),
            ],
            outputs: [p.PF12.into(), p.PF13.into(), p.PF14.into(), p.PF15.into(), p.PF3.into(), p.PF5.into()],
        },
    };
    let board = Stm32Board {
        mac,
        factory_reset,
        eth,
        seed: u64::from_le_bytes(seed),
        isn_key,
        entropy,
        led,
        reset_cause,
        boot,
    };
    (board, settings_flash, io)
}

/// The reset cause from RCC_CSR's flags (RM0090 §6.3.21, the F42x/F43x's RCC chapter), which are then cleared (RMVF) so
/// the next start tells its own. A power-on also sets the pin flag: it is checked first. (The
/// PAC names IWDGRSTF `wdgrstf` and PINRSTF `padrstf`.)
fn reset_cause() -> remodaq_shared::diagnostics::ResetCause {
    use remodaq_shared::diagnostics::ResetCause;
    let rcc = embassy_stm32::pac::RCC;
    let csr = rcc.csr().read();
    let cause = if csr.porrstf() {
        ResetCause::PowerOn
    } else if csr.borrstf() {
        ResetCause::BrownOut
    } else if csr.wdgrstf() || csr.wwdgrstf() {
        ResetCause::Watchdog
    } else if csr.sftrstf() {
        ResetCause::Software
    } else if csr.padrstf() {
        ResetCause::Pin
    } else {
        ResetCause::Unknown
    };
    rcc.csr().modify(|w| w.set_rmvf(true));
    cause
}

impl Board for Stm32Board {
    type Flash = SettingsFlash;
    const SETTINGS_SIZE: u32 = 64 * 1024;
    type Net = EmbassyNet<Stm32Effects>;
    type Dfu = DfuFlash;
    type BootState = BootStateFlash;

    /// The partitions of memory.x that the bootloader (`bootloader/`) swaps from.
    fn boot_partitions(&mut self) -> Option<(DfuFlash, BootStateFlash)> {
        self.boot.take()
    }
    type Resources = Io;

    fn init(spawner: Spawner) -> (Self, SettingsFlash, Io) {
        init(spawner)
    }

    fn reset_cause(&self) -> remodaq_shared::diagnostics::ResetCause {
        self.reset_cause
    }

    /// The words a restart left in the CCM ([`RETAINED`]).
    fn retained(&mut self) -> Option<remodaq_shared::settings::Retained> {
        take_retained()
    }

    fn factory_reset_requested(&self) -> bool {
        self.factory_reset
    }

    fn mac(&self) -> [u8; 6] {
        self.mac
    }

    fn entropy(&mut self) -> [u8; 32] {
        self.entropy
    }

    /// Starts the network with the stored settings (static IPv4), the watchdog and the
    /// identify LED.
    fn start_network(self, spawner: Spawner, net: NetConfig) -> (EmbassyNet<Stm32Effects>, NetConfig) {
        let Stm32Board { eth, seed, isn_key, led, mac, .. } = self;
        // Only intact SYNs to this MAC and address wait in the ports' backlogs.
        remodaq_net::backlog::identify(mac, net.ip, remodaq_net::backlog::HELD_PER_SOURCE);
        let prefix = net.prefix_len().unwrap_or(24);
        let gateway = (net.gateway != [0; 4]).then(|| Ipv4Address::from(net.gateway));
        let config = embassy_net::Config::ipv4_static(StaticConfigV4 {
            address: Ipv4Cidr::new(Ipv4Address::from(net.ip), prefix),
            gateway,
            dns_servers: heapless::Vec::new(),
        });
        // The sockets' state: the CPU's alone, in the CCM (docs/design.md, "Memory plan").
        #[unsafe(link_section = ".bss.ccm.RESOURCES")]
        static RESOURCES: StaticCell<StackResources<STACK_SOCKETS>> = StaticCell::new();
        let (stack, runner) =
            embassy_net::new(Backlogged::new(eth, GATES, isn_key), config, RESOURCES.init(StackResources::new()), seed);
        spawn(spawner, net_task(runner), "net");
        spawn(spawner, identify_task(led), "identify");
        info!("network: {}.{}.{}.{}/{} port {}", net.ip[0], net.ip[1], net.ip[2], net.ip[3], prefix, net.port);
        (EmbassyNet { stack, port: net.port, effects: Stm32Effects }, net)
    }

    fn app_alive() {
        HEARTBEAT.beat(health::APP, Instant::now().as_millis());
    }

    /// The realtime executor: polled from the UART4 interrupt (no UART is used on this board,
    /// so only the executor's pender requests it: NVIC STIR, PM0214 §4.3.8), at priority 8 of
    /// 16 (the F429 implements 4 priority bits, PM0214 §4.3.7): it preempts the main executor
    /// (UART5's interrupt at 15, [`executor`]) and the background one (thread mode), and is
    /// preempted by the drivers' interrupts (embassy-stm32 0.6 leaves them, the DMA's and
    /// TIM2's time driver included, at priority 0), which only wake tasks. Set before `start`,
    /// which unmasks it (embassy-executor 0.10 `InterruptExecutor`).
    fn realtime(_: Spawner) -> SendSpawner {
        use embassy_stm32::interrupt::{InterruptExt, Priority};
        interrupt::UART4.set_priority(Priority::P8);
        REALTIME.start(interrupt::UART4)
    }
}

/// The realtime executor ([`Board::realtime`]).
static REALTIME: InterruptExecutor = InterruptExecutor::new();

#[interrupt]
#[allow(non_snake_case)]
unsafe fn UART4() {
    // SAFETY: the executor's interrupt handler, its only caller; `start` ran before the
    // interrupt was unmasked.
    unsafe { REALTIME.on_interrupt() }
}

/// What a restart leaves for the next start (the flash commit budgets' debts,
/// `remodaq_shared::settings::Retained`), in the CCM: a system reset does not clear SRAM
/// (RM0090 §2.3: the CCM is data RAM on the D-bus at 0x1000_0000), cortex-m-rt neither
/// zeroes nor loads `.ccmram` (memory.x: NOLOAD), and the bootloader does not use the CCM
/// (boards/stm32/bootloader/memory.x has no CCM region). A power-on leaves garbage, which the
/// words' check refuses.
#[unsafe(link_section = ".ccmram.RETAINED")]
static mut RETAINED: [u32; 4] = [0; 4];

fn keep_retained() {
    let words = remodaq_shared::settings::Retained::now().to_words();
    // SAFETY: a volatile write to a static that only this (just before the reset) and
    // `take_retained` (once, at start) touch.
    unsafe { core::ptr::write_volatile(core::ptr::addr_of_mut!(RETAINED), words) };
}

fn take_retained() -> Option<remodaq_shared::settings::Retained> {
    // SAFETY: read and cleared once, at start, before anything else uses it: volatile
    // accesses to a static in a NOLOAD section.
    let words = unsafe {
        let words = core::ptr::read_volatile(core::ptr::addr_of!(RETAINED));
        core::ptr::write_volatile(core::ptr::addr_of_mut!(RETAINED), [0; 4]);
        words
    };
    remodaq_shared::settings::Retained::from_words(words)
}

/// The discovery service's effects on this board: identify blinks LD1 for 10 s; restart resets
/// the MCU once the reply has had time to leave.
pub struct Stm32Effects;

impl Effects for Stm32Effects {
    async fn apply(&self, effect: Effect) {
        match effect {
            Effect::None => {}
            Effect::Identify => IDENTIFY.signal(()),
            Effect::Restart => {
                info!("restart requested");
                Timer::after(Duration::from_millis(300)).await;
                keep_retained();
                cortex_m::peripheral::SCB::sys_reset();
            }
        }
    }
}

#[embassy_executor::task]
async fn net_task(mut runner: embassy_net::Runner<'static, Backlogged<Device>>) -> ! {
    // The network beats while its task runs and the Ethernet DMA has not stopped on a fatal
    // bus error (ETH_DMASR FBES, RM0090 §33.8.2: the DMA then stops until reset), so a wedged
    // MAC ends in a watchdog reset instead of a module that never answers again.
    let beat = async {
        loop {
            if !embassy_stm32::pac::ETH.ethernet_dma().dmasr().read().fbes() {
                HEARTBEAT.beat(health::NET, Instant::now().as_millis());
            } else {
                error!("ethernet: DMA fatal bus error");
            }
            Timer::after(FEED_EVERY / 2).await;
        }
    };
    match embassy_futures::select::select(runner.run(), beat).await {
        embassy_futures::select::Either::First(never) | embassy_futures::select::Either::Second(never) => never,
    }
}

/// Blinks LD1 (5 Hz) for 10 s each time discovery asks to identify the module.
#[embassy_executor::task]
async fn identify_task(mut led: Output<'static>) -> ! {
    loop {
        IDENTIFY.wait().await;
        for _ in 0..50 {
            led.set_high();
            Timer::after_millis(100).await;
            led.set_low();
            Timer::after_millis(100).await;
        }
    }
}

#[embassy_executor::task]
async fn watchdog_task(mut wdg: IndependentWatchdog<'static, IWDG>) -> ! {
    // Started (and fed last) in `init`.
    wdg.pet();
    loop {
        Timer::after(FEED_EVERY).await;
        let now = Instant::now();
        let starting = now.as_millis() < START_GRACE.as_millis() && !HEARTBEAT.all_started();
        if starting || HEARTBEAT.all_alive(now.as_millis(), ALIVE_WINDOW.as_millis() as u32) {
            wdg.pet();
        } else {
            error!("watchdog: a task stopped beating, not feeding");
        }
    }
}
