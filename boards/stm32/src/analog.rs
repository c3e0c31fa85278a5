//! The 8318's analog front end on this board: an AD7124-8 on SPI1 (mode 3, 2.8 MHz, DMA) with
//! its chip select on PD14, and the cold-junction NTC divider (10 kohm from VDDA, NTC to
//! ground) on ADC1 at PA3, read ratiometrically against VDDA. On the Nucleo-F429ZI: SCK PB3,
//! MISO PB4, MOSI PB5 (SPI1's alternate pins: PA7 is the Ethernet's CRS_DV), CS PD14 (D10),
//! NTC PA3 (A0).

use embassy_stm32::adc::{Adc, SampleTime};
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::mode::Async;
use embassy_stm32::peripherals::{ADC1, DMA2_CH2, DMA2_CH3, PA3};
use embassy_stm32::spi::{self, Spi, MODE_3};
use embassy_stm32::time::Hertz;
use embassy_stm32::{bind_interrupts, dma, Peri};
use embassy_time::Delay;
use embedded_hal_bus::spi::ExclusiveDevice;
use remodaq_8318::ad7124::{Ad7124FrontEnd, NtcDivider};
use remodaq_8318::M8318;
use remodaq_shared::board::IoFor;

use crate::resources::{AnalogPeripherals, Io};
use crate::Stm32Board;

bind_interrupts!(struct Irqs {
    DMA2_STREAM2 => dma::InterruptHandler<DMA2_CH2>;
    DMA2_STREAM3 => dma::InterruptHandler<DMA2_CH3>;
});

/// The AD7124-8 as an `embedded-hal-async` SPI device.
pub type AdcSpi = ExclusiveDevice<Spi<'static, Async, spi::mode::Master>, Output<'static>, Delay>;

/// The cold-junction sensor input.
pub struct NtcInput {
    adc: Adc<'static, ADC1>,
    pin: Peri<'static, PA3>,
}

impl NtcDivider for NtcInput {
    fn ratio(&mut self) -> f64 {
        f64::from(self.adc.blocking_read(&mut self.pin, SampleTime::CYCLES480)) / 4095.0
    }
}

/// The 8318's front end on this board.
pub type FrontEnd = Ad7124FrontEnd<AdcSpi, NtcInput>;

impl IoFor<M8318> for Stm32Board {
    type Io = FrontEnd;

    fn io(resources: Io) -> FrontEnd {
        let (spi, ntc) = resources.analog.start();
        Ad7124FrontEnd::new(spi, ntc)
    }
}

impl AnalogPeripherals {
    /// Brings up the SPI bus and the ADC: the AD7124-8 device and the NTC input.
    pub fn start(self) -> (AdcSpi, NtcInput) {
        let mut config = spi::Config::default();
        config.mode = MODE_3;
        // SCLK at most 5 MHz (AD7124-8 datasheet, timing characteristics, t3/t4 >= 100 ns).
        // SPI1 runs from APB2 (90 MHz) through a power-of-two divider that embassy picks from
        // 90 MHz / f (spi/mod.rs, compute_baud_rate): 4 MHz gave /16 = 5.625 MHz, too fast.
        // 90 MHz / 32 = 2.8125 MHz.
        config.frequency = Hertz(2_812_500);
        let bus = Spi::new(self.spi, self.sck, self.mosi, self.miso, self.tx_dma, self.rx_dma, Irqs, config);
        let cs = Output::new(self.cs, Level::High, Speed::High);
        let Ok(device) = ExclusiveDevice::new(bus, cs, Delay);
        (device, NtcInput { adc: Adc::new(self.adc), pin: self.ntc })
    }
}
