//! The 8318 on the STM32 board (Nucleo-F429ZI reference hardware).

use defmt_rtt as _;
use panic_probe as _;

use embassy_executor::Spawner;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use remodaq_8318::acquisition::{self, AnalogFrontEnd, Measurement};
use remodaq_8318::ad7124::{ntc_celsius, Ad7124, Error as AdcError};
use remodaq_8318::map::Map8318;
use remodaq_8318::settings::Settings;
use remodaq_board_stm32::analog::{AdcSpi, NtcInput};
use remodaq_board_stm32::{spawn, SettingsFlash, HEARTBEAT, SETTINGS_SIZE};
use remodaq_shared::settings::SettingsStore;
use remodaq_shared::{error, health};
use static_cell::StaticCell;

type Map = Mutex<CriticalSectionRawMutex, Map8318<SettingsFlash>>;

remodaq_shared::embassy_net_tasks!(Map, remodaq_board_stm32::discovery::run);

static MAP: StaticCell<Map> = StaticCell::new();

/// Starts the module's tasks.
pub async fn run(spawner: Spawner) {
    let (board, settings_flash, io) = remodaq_board_stm32::init();
    let mut store = SettingsStore::<SettingsFlash, Settings>::open(
        settings_flash,
        const { SettingsStore::<SettingsFlash, Settings>::config(0..SETTINGS_SIZE) },
    )
    .await;
    board.factory_reset(&mut store).await;
    let net = store.get().net;
    let identity = board.identity(remodaq_8318::MODULE_NAME, remodaq_8318::MODEL, net);
    let map: &'static Map = MAP.init(Mutex::new(Map8318::new(store)));
    let stack = board.start(&spawner, &net);
    spawn_network(&spawner, stack, net.port, map, identity);
    let (spi, ntc) = io.analog.start();
    spawn(&spawner, app_task(FrontEnd { adc: Ad7124::new(spi), ntc, ready: false }, map), "app");
}

/// The acquisition cycle (10 Hz); each completed cycle is the application's heartbeat.
#[embassy_executor::task]
async fn app_task(mut fe: FrontEnd, map: &'static Map) -> ! {
    acquisition::run(&mut fe, map, || HEARTBEAT.beat(health::APP)).await
}

/// The analog front end of this board: the AD7124-8 and the cold-junction NTC. A chip that
/// fails to initialise is tried again at the next conversion (its channels read FFFFh).
struct FrontEnd {
    adc: Ad7124<AdcSpi>,
    ntc: NtcInput,
    ready: bool,
}

/// Why the front end could not convert.
#[derive(Debug, defmt::Format)]
enum FrontEndError {
    /// The AD7124-8 did not answer as expected.
    Adc,
    /// The NTC reads shorted or open.
    Ntc,
}

impl FrontEnd {
    async fn adc<T>(
        &mut self,
        result: Result<
            T,
            AdcError<embedded_hal_bus::spi::DeviceError<embassy_stm32::spi::Error, core::convert::Infallible>>,
        >,
    ) -> Result<T, FrontEndError> {
        result.map_err(|e| {
            self.ready = false;
            error!("AD7124-8: {}", defmt::Debug2Format(&e));
            FrontEndError::Adc
        })
    }
}

impl AnalogFrontEnd for FrontEnd {
    type Error = FrontEndError;

    async fn measure(&mut self, channel: u8, span_mv: f64, detect_open: bool) -> Result<Measurement, Self::Error> {
        if !self.ready {
            let init = self.adc.init().await;
            self.adc(init).await?;
            self.ready = true;
        }
        let m = self.adc.measure(channel, span_mv, detect_open).await;
        Ok(self.adc(m).await?.map_or(Measurement::Open, Measurement::Millivolts))
    }

    async fn cold_junction_c(&mut self) -> Result<f64, Self::Error> {
        ntc_celsius(self.ntc.ratio()).ok_or(FrontEndError::Ntc)
    }
}
