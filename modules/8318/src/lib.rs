//! RemoDAQ-8318 module logic (`no_std`, no hardware): settings schema and Modbus register map
//! (spec §2), input types and scaling, thermocouple maths, the acquisition cycle, and the
//! AD7124-8 front end with its recovery policy. A board supplies the flash and the analog
//! front end ([`acquisition::AnalogFrontEnd`]); [`M8318`] is the module in the board contract.
#![no_std]
#![warn(missing_docs)]

pub mod acquisition;
pub mod ad7124;
pub mod input;
pub mod map;
pub mod settings;
mod snapshot;
pub mod thermocouple;

use embedded_storage_async::nor_flash::NorFlash;
use remodaq_shared::board::{Module, Runs, Shared};
use remodaq_shared::module::Store;

pub use remodaq_protocol::m8318::{MODEL, MODULE_NAME};

/// The RemoDAQ-8318.
pub struct M8318;

impl Module for M8318 {
    const MODULE_NAME: u16 = MODULE_NAME;
    const MODEL: &'static str = MODEL;
    type Settings = settings::Settings;
    type State = ();
    type Map<F: NorFlash + 'static> = map::Map8318<'static, F>;

    fn state(_: &settings::Settings) {}

    fn map<F: NorFlash + 'static>(
        store: &'static Store<F, settings::Settings>,
        settings: &settings::Settings,
        _: &'static (),
    ) -> Self::Map<F> {
        map::Map8318::new(store, settings)
    }
}

impl<A: acquisition::AnalogFrontEnd> Runs<A> for M8318 {
    async fn run<F: NorFlash + 'static>(
        mut front_end: A,
        _: &'static (),
        map: &'static Shared<Self::Map<F>>,
        alive: impl FnMut(),
    ) -> ! {
        acquisition::run(&mut front_end, map, alive).await
    }
}
