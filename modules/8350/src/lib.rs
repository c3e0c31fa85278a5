//! RemoDAQ-8350 module logic (`no_std`, no hardware): the digital-input engine (state,
//! counters, latches, frequency), the pulse/level output engine, the settings schema, the
//! Modbus register map (spec §3) and the I/O loop. A board supplies the flash, the input
//! capture and the output pattern ([`io::InputCapture`], [`io::OutputPattern`]); [`M8350`] is
//! the module in the board contract.
#![no_std]
#![warn(missing_docs)]

pub mod di;
pub mod io;
pub mod map;
pub mod pulse;
pub mod ring;
pub mod settings;
pub mod watchdog;

use core::cell::RefCell;

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_shared::board::{Module, RunsRealtime};
use remodaq_shared::module::Store;

pub use remodaq_protocol::m8350::{MODEL, MODULE_NAME};

/// The RemoDAQ-8350.
pub struct M8350;

/// The engines, shared by the register map and the I/O loop.
pub type State = io::IoCell<CriticalSectionRawMutex>;

impl Module for M8350 {
    const MODULE_NAME: u16 = MODULE_NAME;
    const MODEL: &'static str = MODEL;
    type Settings = settings::Settings;
    type State = State;
    type Map<F: NorFlash + 'static> = map::Map8350<'static, F, CriticalSectionRawMutex>;

    fn state(settings: &settings::Settings) -> State {
        io::IoCell::new(RefCell::new(io::Io::new(di::SAMPLE_RATE_HZ, settings)))
    }

    fn map<F: NorFlash + 'static>(
        store: &'static Store<F, settings::Settings>,
        settings: &settings::Settings,
        state: &'static State,
    ) -> Self::Map<F> {
        map::Map8350::new(store, settings, state)
    }
}

impl<I: io::InputCapture, O: io::OutputPattern> RunsRealtime<(I, O)> for M8350 {
    async fn run_realtime((inputs, outputs): (I, O), state: &'static State, alive: fn()) -> ! {
        io::run(inputs, outputs, state, alive).await
    }
}
