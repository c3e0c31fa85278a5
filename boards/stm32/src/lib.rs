//! The STM32 board: the Nucleo-F429ZI reference hardware (STM32F429ZI, LAN8742A RMII PHY).
//! Every pin, clock and peripheral choice of the firmware is made here and nowhere else; a port
//! to the RemoDAQ PCB changes this crate only.
#![no_std]
#![cfg(target_os = "none")]

pub mod analog;
pub mod digital;

use defmt_rtt as _;
use panic_probe as _;

use embassy_executor::Spawner;
use embassy_net::{Ipv4Address, Ipv4Cidr, StackResources, StaticConfigV4};
use embassy_stm32::eth::{Ethernet, GenericPhy, PacketQueue, Sma};
use embassy_stm32::flash::{Async, Bank2Region1, Flash};
use embassy_stm32::gpio::{Input, Level, Output, Pull, Speed};
use embassy_stm32::peripherals::{ETH, ETH_SMA, IWDG};
use embassy_stm32::rng::Rng;
use embassy_stm32::time::Hertz;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, eth, flash, peripherals, rng, Config};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Timer};
use remodaq_shared::board::{spawn, Board, Effects};
use remodaq_shared::discovery::Effect;
use remodaq_shared::embassy_net::EmbassyNet;
use remodaq_shared::health::{self, Heartbeat};
use remodaq_shared::net::{mac_from_uid, NetConfig};
use remodaq_shared::{error, info};
use static_cell::StaticCell;

bind_interrupts!(struct Irqs {
    ETH => eth::InterruptHandler;
    HASH_RNG => rng::InterruptHandler<peripherals::RNG>;
    FLASH => flash::InterruptHandler;
});

/// The Ethernet device of this board.
pub type Device = Ethernet<'static, ETH, GenericPhy<Sma<'static, ETH_SMA>>>;
/// The settings flash: bank 2, sectors 12-15 (16 KiB each, 0x0810_0000), see `memory.x`.
pub type SettingsFlash = Bank2Region1<'static, Async>;

/// Sockets: Modbus connection tasks plus the discovery socket, plus slack.
const STACK_SOCKETS: usize = remodaq_shared::modbus::server::SOCKETS + 3;
/// Independent watchdog period; fed every [`FEED_EVERY`] while all watched tasks beat.
const WATCHDOG_TIMEOUT_US: u32 = 4_000_000;
const FEED_EVERY: Duration = Duration::from_millis(1000);

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
    iwdg: embassy_stm32::Peri<'static, IWDG>,
    led: Output<'static>,
}

/// The peripherals reserved for the modules' I/O; each module's image starts its own part
/// (`IoFor`, in `analog.rs` and `digital.rs`) and leaves the rest unused.
pub struct Io {
    /// The 8318's analog front end.
    pub analog: analog::AnalogPeripherals,
    /// The 8350's digital inputs and outputs.
    pub digital: digital::DigitalPeripherals,
}

/// Clocks at 180 MHz from the ST-LINK's 8 MHz MCO (HSE bypass), then the peripherals.
fn init() -> (Stm32Board, SettingsFlash, Io) {
    let mut config = Config::default();
    {
        use embassy_stm32::rcc::*;
        config.rcc.hse = Some(Hse { freq: Hertz(8_000_000), mode: HseMode::Bypass });
        config.rcc.pll_src = PllSource::HSE;
        config.rcc.pll = Some(Pll {
            prediv: PllPreDiv::DIV4,
            mul: PllMul::MUL180,
            divp: Some(PllPDiv::DIV2), // 180 MHz
            divq: None,
            divr: None,
        });
        config.rcc.ahb_pre = AHBPrescaler::DIV1;
        config.rcc.apb1_pre = APBPrescaler::DIV4;
        config.rcc.apb2_pre = APBPrescaler::DIV2;
        config.rcc.sys = Sysclk::PLL1_P;
    }
    let p = embassy_stm32::init(config);

    let mut rng = Rng::new(p.RNG, Irqs);
    let mut seed = [0u8; 8];
    rng.fill_bytes(&mut seed);

    let mac = mac_from_uid(&embassy_stm32::uid::uid());

    static PACKETS: StaticCell<PacketQueue<4, 4>> = StaticCell::new();
    // Nucleo-F429ZI RMII: REF_CLK PA1, MDIO PA2, MDC PC1, CRS_DV PA7, RXD0 PC4, RXD1 PC5,
    // TX_EN PG11, TXD0 PG13, TXD1 PB13.
    let eth = Ethernet::new(
        PACKETS.init(PacketQueue::<4, 4>::new()),
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
        p.ETH_SMA,
        p.PA2,
        p.PC1,
    );

    let settings_flash = Flash::new(p.FLASH, Irqs).into_regions().bank2_region1;
    // LD1 (green, PB0): the "identify" LED.
    let led = Output::new(p.PB0, Level::Low, Speed::Low);
    let factory_reset = Input::new(p.PC13, Pull::Down).is_high();

    let io = Io {
        analog: analog::AnalogPeripherals {
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
        digital: digital::DigitalPeripherals {
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
    let board = Stm32Board { mac, factory_reset, eth, seed: u64::from_le_bytes(seed), iwdg: p.IWDG, led };
    (board, settings_flash, io)
}

impl Board for Stm32Board {
    type Flash = SettingsFlash;
    const SETTINGS_SIZE: u32 = 64 * 1024;
    type Net = EmbassyNet<Stm32Effects>;
    type Resources = Io;

    fn init() -> (Self, SettingsFlash, Io) {
        init()
    }

    fn factory_reset_requested(&self) -> bool {
        self.factory_reset
    }

    fn mac(&self) -> [u8; 6] {
        self.mac
    }

    /// Starts the network with the stored settings (static IPv4), the watchdog and the
    /// identify LED.
    fn start_network(self, spawner: Spawner, net: NetConfig) -> (EmbassyNet<Stm32Effects>, NetConfig) {
        let Stm32Board { eth, seed, iwdg, led, .. } = self;
        let prefix = net.prefix_len().unwrap_or(24);
        let gateway = (net.gateway != [0; 4]).then(|| Ipv4Address::from(net.gateway));
        let config = embassy_net::Config::ipv4_static(StaticConfigV4 {
            address: Ipv4Cidr::new(Ipv4Address::from(net.ip), prefix),
            gateway,
            dns_servers: heapless::Vec::new(),
        });
        static RESOURCES: StaticCell<StackResources<STACK_SOCKETS>> = StaticCell::new();
        let (stack, runner) = embassy_net::new(eth, config, RESOURCES.init(StackResources::new()), seed);
        spawn(spawner, net_task(runner), "net");
        spawn(spawner, watchdog_task(IndependentWatchdog::new(iwdg, WATCHDOG_TIMEOUT_US)), "watchdog");
        spawn(spawner, identify_task(led), "identify");
        info!("network: {}.{}.{}.{}/{} port {}", net.ip[0], net.ip[1], net.ip[2], net.ip[3], prefix, net.port);
        (EmbassyNet { stack, port: net.port, effects: Stm32Effects }, net)
    }

    fn app_alive() {
        HEARTBEAT.beat(health::APP);
    }
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
                cortex_m::peripheral::SCB::sys_reset();
            }
        }
    }
}

#[embassy_executor::task]
async fn net_task(mut runner: embassy_net::Runner<'static, Device>) -> ! {
    let beat = async {
        loop {
            HEARTBEAT.beat(health::NET);
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
    wdg.unleash();
    loop {
        Timer::after(FEED_EVERY).await;
        if HEARTBEAT.all_alive() {
            wdg.pet();
        } else {
            error!("watchdog: a task stopped beating, not feeding");
        }
    }
}
