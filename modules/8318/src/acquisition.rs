//! The acquisition cycle (spec §2.5): every 100 ms, convert every enabled channel and the cold
//! junction, linearise, and publish all values at once.

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::{Duration, Ticker};
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_shared::module::SettingsAccess;
use remodaq_shared::warn;

use crate::input::{InputType, Kind};
use crate::map::Map8318;
use crate::settings::Settings;
pub use crate::snapshot::Snapshot;
use crate::thermocouple::{Inverse, Reference};
pub use remodaq_protocol::m8318::ChannelStatus;

/// Number of analog inputs.
pub const CHANNELS: usize = remodaq_protocol::m8318::CHANNELS;
/// Acquisition period.
pub const PERIOD: Duration = Duration::from_millis(100);
/// Register 40009 when the cold-junction sensor cannot be read (decision): 7FFFh.
pub const CJC_INVALID: i16 = i16::MAX;

/// What the front end saw at a channel's terminals.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Measurement {
    /// Voltage between Vin+ and Vin-, mV.
    Millivolts(f64),
    /// Nothing connected (burnout detection tripped).
    Open,
}

/// The analog front end of a board: converts a channel over a span, reads the cold-junction
/// sensor, detects an open input.
#[allow(async_fn_in_trait)]
pub trait AnalogFrontEnd {
    /// A conversion failed.
    type Error: remodaq_shared::fmt::Loggable;

    /// Converts `channel` (0..8) with a gain that covers ±`span_mv` at the terminals. With
    /// `detect_open` (thermocouples), an open input is reported as [`Measurement::Open`].
    async fn measure(&mut self, channel: u8, span_mv: f64, detect_open: bool) -> Result<Measurement, Self::Error>;

    /// The temperature of the terminals (cold junction), °C.
    async fn cold_junction_c(&mut self) -> Result<f64, Self::Error>;
}

/// The register value of one channel and its status (extensions §2). `cj_emf_mv` is
/// E(t_cj + offset) of the type, `None` when the cold junction is unknown; `open` is the value
/// an open input reads (FFFFh upscale, 0000h downscale).
pub fn channel_value(input: &InputType, m: Measurement, cj_emf_mv: Option<f64>, open: u16) -> (u16, ChannelStatus) {
    let Measurement::Millivolts(mv) = m else { return (open, ChannelStatus::Open) };
    let x = match input.kind {
        Kind::Voltage => mv,
        Kind::Current => mv / crate::input::SHUNT_OHMS,
        Kind::Thermocouple(tc) => {
            let Some(cj) = cj_emf_mv else { return (0xFFFF, ChannelStatus::CjcFault) };
            match tc.temperature_c(mv + cj) {
                Inverse::Below => return (0x0000, ChannelStatus::Under),
                Inverse::Above => return (0xFFFF, ChannelStatus::Over),
                Inverse::Celsius(t) => t,
            }
        }
    };
    let status = if x < input.lo {
        ChannelStatus::Under
    } else if x <= input.hi {
        ChannelStatus::Ok
    } else {
        // Above the range, or not a number (which reads FFFFh).
        ChannelStatus::Over
    };
    (input.raw(x), status)
}

/// Register 40009 of a corrected cold-junction temperature.
pub fn cjc_register(celsius: f64) -> i16 {
    let r = libm::round(celsius * 100.0);
    if r.is_nan() {
        CJC_INVALID
    } else {
        r.clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
    }
}

/// The cycle's faults in the diagnostics registers (extensions §1), logged when they change;
/// the inputs are valid from the first cycle on.
fn report(snapshot: &Snapshot) {
    use remodaq_shared::diagnostics::{status, DIAGNOSTICS};
    DIAGNOSTICS.set(status::INPUTS_PENDING, false);
    if DIAGNOSTICS.set(status::FRONT_END_FAULT, snapshot.front_end_fault) {
        match snapshot.front_end_fault {
            true => remodaq_shared::error!("self-test: front-end fault (conversions fail)"),
            false => remodaq_shared::info!("self-test: front end ok"),
        }
    }
    if DIAGNOSTICS.set(status::CJC_FAULT, snapshot.cjc_fault) {
        match snapshot.cjc_fault {
            true => remodaq_shared::error!("self-test: cold-junction sensor fault"),
            false => remodaq_shared::info!("self-test: cold-junction sensor ok"),
        }
    }
}

/// Runs one acquisition cycle.
pub async fn acquire<A: AnalogFrontEnd>(fe: &mut A, settings: &Settings) -> Snapshot {
    let mut snapshot = Snapshot::default();
    let Some(input) = InputType::from_code(settings.input_type) else { return snapshot };
    let offset = f64::from(settings.cjc_offset) / 100.0;
    let cold_junction = match fe.cold_junction_c().await {
        Ok(t) => Some(t + offset),
        Err(e) => {
            warn!("8318: cold junction not read: {:?}", e);
            snapshot.cjc_fault = true;
            None
        }
    };
    snapshot.cjc = cold_junction.map_or(CJC_INVALID, cjc_register);
    let cj_emf = match input.thermocouple() {
        Some(tc) => cold_junction.map(|t| tc.emf_clamped_mv(t)),
        None => Some(0.0),
    };
    let detect_open = input.thermocouple().is_some();
    let open = if settings.downscale { 0x0000 } else { 0xFFFF };
    for ch in 0..CHANNELS {
        if settings.enable_mask & (1 << ch) == 0 {
            snapshot.status[ch] = ChannelStatus::Disabled;
            continue;
        }
        (snapshot.values[ch], snapshot.status[ch]) =
            match fe.measure(ch as u8, crate::input::span_mv(&input), detect_open).await {
                Ok(m) => channel_value(&input, m, cj_emf, open),
                Err(e) => {
                    warn!("8318: channel {} not converted: {:?}", ch, e);
                    snapshot.front_end_fault = true;
                    (0xFFFF, ChannelStatus::FrontEndFault)
                }
            };
    }
    snapshot
}

/// The application task's body: one cycle every [`PERIOD`], published to the map at once;
/// `alive` is called after each cycle (the watchdog heartbeat).
pub async fn run<R: RawMutex, F: NorFlash, A: AnalogFrontEnd>(
    fe: &mut A,
    map: &Mutex<R, Map8318<'_, F>>,
    mut alive: impl FnMut(),
) -> ! {
    let mut ticker = Ticker::every(PERIOD);
    loop {
        ticker.next().await;
        let settings = *map.lock().await.settings();
        let snapshot = acquire(fe, &settings).await;
        map.lock().await.publish(snapshot);
        report(&snapshot);
        alive();
    }
}
