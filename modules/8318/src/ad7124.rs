//! Register-level driver of the AD7124-8 24-bit sigma-delta ADC (the STM32 board's analog
//! front end), over any `embedded-hal-async` SPI device. No hardware in it: the host tests run
//! it against a register-level fake of the chip.
//!
//! Use: internal 2.5 V reference, full power, bipolar inputs with buffers, one differential
//! pair per channel (Vin n+ = AIN 2n, Vin n- = AIN 2n+1), single conversions. Setup 0 measures
//! (burnout currents off, sinc4 at 640 SPS); setup 1 checks for an open input with the 4 µA
//! burnout currents on (an open thermocouple then reads at positive full scale) and a fast
//! filter, so the measurement itself never carries the burnout current's error.

use embassy_time::{Duration, Instant, Timer};
use embedded_hal_async::spi::{Operation, SpiDevice};

/// Register addresses.
pub mod reg {
    /// Status (read).
    pub const STATUS: u8 = 0x00;
    /// ADC control.
    pub const ADC_CONTROL: u8 = 0x01;
    /// Conversion data.
    pub const DATA: u8 = 0x02;
    /// Device id.
    pub const ID: u8 = 0x05;
    /// Error flags.
    pub const ERROR: u8 = 0x06;
    /// Channel 0 (of 16).
    pub const CHANNEL_0: u8 = 0x09;
    /// Configuration (setup) 0 (of 8).
    pub const CONFIG_0: u8 = 0x19;
    /// Filter (setup) 0 (of 8).
    pub const FILTER_0: u8 = 0x21;

    /// Size of a register in bytes.
    pub fn size(addr: u8) -> usize {
        match addr {
            STATUS | ID | 0x08 => 1,
            ADC_CONTROL | 0x04 | 0x09..=0x20 => 2,
            _ => 3,
        }
    }
}

/// IO_CONTROL_2: VBIAS enables, bit n = AINn (datasheet, IO_CONTROL_2 register).
const IO_CONTROL_2: u8 = 0x04;
/// VBIAS on every pair's negative input (AIN1, AIN3, ... AIN15): a floating thermocouple then
/// sits at AVDD/2, inside the buffered inputs' common-mode range (datasheet, "Bias voltage
/// generator"; thermocouple application notes bias the negative lead).
const VBIAS_NEGATIVE_INPUTS: u32 = 0xAAAA;
/// STATUS: POR_FLAG, set by a power-on or software reset until the reset is complete.
const STATUS_POR: u8 = 1 << 4;
/// After a reset, wait this long before the first register access: the datasheet allows
/// about 2 ms for the internal reset; ADI's own no-OS driver waits 4 ms.
const RESET_WAIT: Duration = Duration::from_millis(4);
/// ADC_CONTROL: internal reference on, full power, and the mode.
const ADC_CONTROL_BASE: u16 = 1 << 8 | 0b10 << 6;
const MODE_SINGLE: u16 = 1 << 2;
const MODE_STANDBY: u16 = 2 << 2;
/// STATUS: RDY (active low) and the error flag.
const STATUS_NOT_READY: u8 = 1 << 7;
const STATUS_ERROR: u8 = 1 << 6;
/// CONFIG: bipolar, reference and input buffers, internal reference; burnout 4 µA.
const CONFIG_BASE: u16 = 1 << 11 | 1 << 8 | 1 << 7 | 1 << 6 | 1 << 5 | 0b10 << 3;
const CONFIG_BURNOUT_4UA: u16 = 0b11 << 9;
/// FILTER: sinc4, FS = 30 (640 SPS at full power) for measuring, FS = 4 for open checks.
const FILTER_MEASURE: u32 = 30;
const FILTER_OPEN_CHECK: u32 = 4;
/// Reference voltage, mV.
pub const VREF_MV: f64 = 2500.0;
/// The modulator clock at full power, Hz (datasheet: 614.4 kHz).
const MCLK_FULL_POWER_HZ: u64 = 614_400;

/// The time a single conversion takes with the sinc4 filter at FS, µs: four output periods
/// (zero-latency single conversion: the filter settles in 4 / ODR, ODR = fCLK / (32 x FS);
/// datasheet, "Sinc4 filter", settling time).
pub const fn sinc4_settling_us(fs: u32) -> u64 {
    4 * 32 * fs as u64 * 1_000_000 / MCLK_FULL_POWER_HZ
}

/// How long to wait for a conversion with the filter at FS: twice its settling time and 2 ms
/// more (the measurement filter: 6.25 ms settling, 14.5 ms timeout).
pub const fn conversion_timeout(fs: u32) -> Duration {
    Duration::from_micros(2 * sinc4_settling_us(fs) + 2_000)
}
/// An open-check reading at or above this code is an open input (positive full scale).
const OPEN_CODE: u32 = 0xFF_F000;
/// Known AD7124-8 ids (silicon revisions).
const IDS: [u8; 3] = [0x14, 0x16, 0x17];

/// What went wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Error<E> {
    /// The SPI bus failed.
    Spi(E),
    /// The chip answered an unknown id (not an AD7124-8, or no chip).
    Id(u8),
    /// No conversion result in time.
    Timeout,
    /// The chip stayed in reset (POR_FLAG set) after the reset wait.
    StillInReset,
    /// A register read back other than what was written: (register, written, read).
    Readback(u8, u32, u32),
}

/// The PGA setting (log2 of the gain) whose full scale covers ±`span_mv`.
pub fn gain_for_span(span_mv: f64) -> u8 {
    (0..=7u8).rev().find(|g| VREF_MV / f64::from(1u16 << g) >= span_mv).unwrap_or(0)
}

/// mV at the inputs of a bipolar conversion code at gain 2^`gain_log2`.
pub fn code_to_mv(code: u32, gain_log2: u8) -> f64 {
    (f64::from(code) - 8_388_608.0) / 8_388_608.0 * VREF_MV / f64::from(1u16 << gain_log2)
}

/// The ADC.
pub struct Ad7124<S> {
    spi: S,
    /// Last CONFIG written per setup, to skip rewriting it.
    config: [Option<u16>; 2],
    /// Last IO_CONTROL_2 (VBIAS) written.
    vbias: Option<u32>,
}

impl<S: SpiDevice> Ad7124<S> {
    /// Wraps the SPI device; call [`Self::init`] before converting.
    pub fn new(spi: S) -> Self {
        Self { spi, config: [None; 2], vbias: None }
    }

    /// Gives the SPI device back.
    pub fn into_inner(self) -> S {
        self.spi
    }

    /// Resets the chip, waits for the reset to complete, checks its id and sets up reference,
    /// power and filters, reading each back.
    pub async fn init(&mut self) -> Result<(), Error<S::Error>> {
        // 64 ones on DIN reset the chip; writes during the internal reset are lost (and left
        // FILTER_0 at its reset value, whose conversions outlast the timeout).
        self.spi.write(&[0xFF; 8]).await.map_err(Error::Spi)?;
        Timer::after(RESET_WAIT).await;
        // POR_FLAG reads 1 until the reset is complete (the read clears it).
        let mut reset_done = false;
        for _ in 0..10 {
            if self.read(reg::STATUS).await? as u8 & STATUS_POR == 0 {
                reset_done = true;
                break;
            }
            Timer::after_millis(1).await;
        }
        if !reset_done {
            return Err(Error::StillInReset);
        }
        let id = self.read(reg::ID).await? as u8;
        if !IDS.contains(&id) {
            return Err(Error::Id(id));
        }
        self.write_checked(reg::ADC_CONTROL, u32::from(ADC_CONTROL_BASE | MODE_STANDBY)).await?;
        self.write_checked(reg::FILTER_0, FILTER_MEASURE).await?;
        self.write_checked(reg::FILTER_0 + 1, FILTER_OPEN_CHECK).await?;
        self.config = [None; 2];
        self.vbias = None;
        Ok(())
    }

    /// Writes a register and reads it back.
    async fn write_checked(&mut self, addr: u8, value: u32) -> Result<(), Error<S::Error>> {
        self.write(addr, value).await?;
        match self.read(addr).await? {
            read if read == value => Ok(()),
            read => Err(Error::Readback(addr, value, read)),
        }
    }

    /// Reads a register.
    pub async fn read(&mut self, addr: u8) -> Result<u32, Error<S::Error>> {
        let n = reg::size(addr);
        let mut buf = [0u8; 3];
        self.spi
            .transaction(&mut [Operation::Write(&[0x40 | addr]), Operation::Read(&mut buf[..n])])
            .await
            .map_err(Error::Spi)?;
        Ok(buf[..n].iter().fold(0u32, |acc, b| acc << 8 | u32::from(*b)))
    }

    /// Writes a register.
    pub async fn write(&mut self, addr: u8, value: u32) -> Result<(), Error<S::Error>> {
        let n = reg::size(addr);
        let mut frame = [addr & 0x3F, 0, 0, 0];
        for i in 0..n {
            frame[1 + i] = (value >> (8 * (n - 1 - i))) as u8;
        }
        self.spi.write(&frame[..=n]).await.map_err(Error::Spi)
    }

    /// One single conversion of differential pair `pair` on `setup` at gain 2^`gain_log2`:
    /// the raw code and whether the chip flagged an error (e.g. saturation).
    async fn convert(&mut self, pair: u8, setup: u8, gain_log2: u8) -> Result<(u32, bool), Error<S::Error>> {
        let burnout = if setup == 1 { CONFIG_BURNOUT_4UA } else { 0 };
        let config = CONFIG_BASE | burnout | u16::from(gain_log2 & 7);
        if self.config[usize::from(setup)] != Some(config) {
            self.write_checked(reg::CONFIG_0 + setup, u32::from(config)).await?;
            self.config[usize::from(setup)] = Some(config);
        }
        let channel = 1 << 15 | u16::from(setup) << 12 | u16::from(2 * pair) << 5 | u16::from(2 * pair + 1);
        self.write(reg::CHANNEL_0, u32::from(channel)).await?;
        self.write(reg::ADC_CONTROL, u32::from(ADC_CONTROL_BASE | MODE_SINGLE)).await?;
        let fs = if setup == 1 { FILTER_OPEN_CHECK } else { FILTER_MEASURE };
        let deadline = Instant::now() + conversion_timeout(fs);
        let status = loop {
            let status = self.read(reg::STATUS).await? as u8;
            if status & STATUS_NOT_READY == 0 {
                break status;
            }
            if Instant::now() >= deadline {
                return Err(Error::Timeout);
            }
            Timer::after_micros(500).await;
        };
        let code = self.read(reg::DATA).await?;
        Ok((code, status & STATUS_ERROR != 0))
    }

    /// Measures pair `pair` over ±`span_mv`: `None` when `detect_open` finds it open, else mV.
    /// Thermocouples (`detect_open`) get VBIAS on their negative inputs; other inputs none
    /// (a grounded voltage source must not be pulled).
    pub async fn measure(&mut self, pair: u8, span_mv: f64, detect_open: bool) -> Result<Option<f64>, Error<S::Error>> {
        let gain = gain_for_span(span_mv);
        let vbias = if detect_open { VBIAS_NEGATIVE_INPUTS } else { 0 };
        if self.vbias != Some(vbias) {
            self.write_checked(IO_CONTROL_2, vbias).await?;
            self.vbias = Some(vbias);
        }
        if detect_open {
            let (code, error) = self.convert(pair, 1, gain).await?;
            if code >= OPEN_CODE || error {
                return Ok(None);
            }
        }
        let (code, _) = self.convert(pair, 0, gain).await?;
        Ok(Some(code_to_mv(code, gain)))
    }
}

/// The cold-junction NTC (10 kohm at 25 °C, beta 3435 K) in a divider with a 10 kohm resistor
/// from the ADC's reference, NTC to ground: `ratio` = V(NTC) / V(reference). `None` for a
/// shorted or open sensor.
pub fn ntc_celsius(ratio: f64) -> Option<f64> {
    const R_FIXED: f64 = 10_000.0;
    const R_25: f64 = 10_000.0;
    const BETA: f64 = 3435.0;
    if !(0.01..=0.99).contains(&ratio) {
        return None;
    }
    let r = R_FIXED * ratio / (1.0 - ratio);
    Some(1.0 / (1.0 / 298.15 + libm::log(r / R_25) / BETA) - 273.15)
}

/// The cold-junction NTC divider of the front end, as the board reads it.
pub trait NtcDivider {
    /// V(NTC) / VDDA, 0..1.
    fn ratio(&mut self) -> f64;
}

/// Why the front end could not convert.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrontEndError {
    /// The AD7124-8 did not answer as expected (the chip is set up again before the next
    /// conversion).
    Adc,
    /// The NTC reads shorted or open.
    Ntc,
}

/// The 8318's analog front end: the AD7124-8 and the cold-junction NTC, with the recovery
/// policy. A chip that fails (bus error, wrong id, a conversion that never finishes) is reset
/// and set up again at the next conversion; until then its channels read FFFFh (spec §2.3:
/// the acquisition cycle maps a failed conversion there).
pub struct Ad7124FrontEnd<S, N> {
    adc: Ad7124<S>,
    ntc: N,
    ready: bool,
    failures: u32,
}

impl<S: SpiDevice, N: NtcDivider> Ad7124FrontEnd<S, N> {
    /// The front end over the chip's SPI device and the NTC divider; the chip is set up at the
    /// first conversion.
    pub fn new(spi: S, ntc: N) -> Self {
        Self { adc: Ad7124::new(spi), ntc, ready: false, failures: 0 }
    }

    /// Conversions or set-ups that failed since start-up.
    pub fn failures(&self) -> u32 {
        self.failures
    }

    /// Gives the SPI device back.
    pub fn into_inner(self) -> (S, N) {
        (self.adc.into_inner(), self.ntc)
    }

    fn failed<E: core::fmt::Debug>(&mut self, e: E) -> FrontEndError {
        self.ready = false;
        self.failures = self.failures.saturating_add(1);
        remodaq_shared::error!("AD7124-8: {:?}", remodaq_shared::fmt::Debug(&e));
        FrontEndError::Adc
    }
}

impl<S: SpiDevice, N: NtcDivider> crate::acquisition::AnalogFrontEnd for Ad7124FrontEnd<S, N> {
    type Error = FrontEndError;

    async fn measure(
        &mut self,
        channel: u8,
        span_mv: f64,
        detect_open: bool,
    ) -> Result<crate::acquisition::Measurement, FrontEndError> {
        use crate::acquisition::Measurement;
        if !self.ready {
            if let Err(e) = self.adc.init().await {
                return Err(self.failed(e));
            }
            self.ready = true;
        }
        match self.adc.measure(channel, span_mv, detect_open).await {
            Ok(m) => Ok(m.map_or(Measurement::Open, Measurement::Millivolts)),
            Err(e) => Err(self.failed(e)),
        }
    }

    async fn cold_junction_c(&mut self) -> Result<f64, FrontEndError> {
        ntc_celsius(self.ntc.ratio()).ok_or(FrontEndError::Ntc)
    }
}
