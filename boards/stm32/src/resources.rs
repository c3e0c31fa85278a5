//! The peripherals and pins the board reserves for the modules' I/O (the pin plan of
//! docs/design.md): handed by `init` to the module's image, which starts its own part
//! (`IoFor`, in `analog.rs` and `digital.rs`).

use embassy_stm32::gpio::AnyPin;
use embassy_stm32::peripherals::{
    ADC1, DMA2_CH1, DMA2_CH2, DMA2_CH3, DMA2_CH5, PA3, PB3, PB4, PB5, PD14, SPI1, TIM1, TIM8,
};
use embassy_stm32::Peri;

/// The peripherals reserved for the modules' I/O; each module's image starts its own part
/// (`IoFor`, in `analog.rs` and `digital.rs`) and leaves the rest unused.
pub struct Io {
    /// The 8318's analog front end.
    pub analog: AnalogPeripherals,
    /// The 8350's digital inputs and outputs.
    pub digital: DigitalPeripherals,
}

/// The peripherals reserved for the analog front end.
pub struct AnalogPeripherals {
    pub(crate) spi: Peri<'static, SPI1>,
    pub(crate) sck: Peri<'static, PB3>,
    pub(crate) miso: Peri<'static, PB4>,
    pub(crate) mosi: Peri<'static, PB5>,
    pub(crate) cs: Peri<'static, PD14>,
    pub(crate) tx_dma: Peri<'static, DMA2_CH3>,
    pub(crate) rx_dma: Peri<'static, DMA2_CH2>,
    pub(crate) adc: Peri<'static, ADC1>,
    pub(crate) ntc: Peri<'static, PA3>,
}

/// The peripherals reserved for the digital I/O.
pub struct DigitalPeripherals {
    pub(crate) tim_in: Peri<'static, TIM1>,
    pub(crate) tim_out: Peri<'static, TIM8>,
    pub(crate) dma_in: Peri<'static, DMA2_CH5>,
    pub(crate) dma_out: Peri<'static, DMA2_CH1>,
    /// PE2..PE13, in DI order.
    pub(crate) di: [Peri<'static, AnyPin>; 12],
    /// PF12, PF13, PF14, PF15, PF3, PF5, in DO order (see `DO_PINS`).
    pub(crate) outputs: [Peri<'static, AnyPin>; 6],
}
