/// Independent watchdog period, nominal: the application's (boards/stm32/src/lib.rs), and the
/// bootloader's, which starts the IWDG just before it jumps to the application (stm32 review
/// R2). One value for both, so that the application's own set-up writes the prescaler and
/// reload the running watchdog already has. The IWDG runs from the LSI, 17 to 47 kHz on the
/// F429 (datasheet DS9405, LSI oscillator characteristics) against the 32 kHz embassy computes
/// the reload with: 8 s nominal is 5.4 s to 15 s real.
pub const WATCHDOG_TIMEOUT_US: u32 = 8_000_000;
