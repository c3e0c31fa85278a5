//! An external interrupt of the machine by its number, for the NVIC (the LAN9118's, the
//! realtime executor's).

use cortex_m::interrupt::InterruptNumber;

#[derive(Clone, Copy)]
pub(crate) struct Irq(pub(crate) u16);

// SAFETY: the number is a valid external interrupt of this machine.
unsafe impl InterruptNumber for Irq {
    fn number(self) -> u16 {
        self.0
    }
}
