//! The Nucleo-F429ZI's LAN8742A PHY (RMII), with what embassy-stm32 0.6's `GenericPhy` leaves
//! out: after auto-negotiation the MAC is set to the speed and duplex the PHY negotiated.
//!
//! embassy-stm32 0.6 (`eth/v1/mod.rs`, MAC set-up) fixes MACCR at 100 Mbit/s full duplex and
//! `GenericPhy::poll_link` reads only the basic status register, so a 10 Mbit/s or
//! half-duplex link partner got a MAC that disagreed with the PHY (a broken link). Here
//! `poll_link` reads the LAN8742A's PHY Special Control/Status register (31; datasheet
//! §4.2.22: bit 12 auto-negotiation done, bits 4:2 speed indication 001 10BASE-T half, 101
//! 10BASE-T full, 010 100BASE-TX half, 110 100BASE-TX full) when the link comes up, and writes
//! MACCR FES (bit 14, speed) and DM (bit 11, duplex) to match (RM0090 §33.8.1, ETH_MACCR),
//! with the MAC stopped meanwhile (`set_mac`).
//! A PHY that never answers is logged, not a panic (`GenericPhy::new_auto` panics).

use core::future::Future;
use core::pin::pin;
use core::task::Context;

use embassy_stm32::eth::{Phy, StationManagement};
use embassy_stm32::pac;
use embassy_stm32::pac::eth::vals::{Dm, Fes, Ftf, St};
use embassy_time::{Duration, Timer};
use remodaq_shared::{error, info};

/// Basic control register: reset, auto-negotiation enable and restart, 100 Mbit/s.
const BCR: u8 = 0;
const BCR_RESET: u16 = 1 << 15;
const BCR_AUTONEG: u16 = 1 << 12 | 1 << 9 | 1 << 13;
/// Basic status register: link up, auto-negotiation complete.
const BSR: u8 = 1;
const BSR_LINK: u16 = 1 << 2;
const BSR_AUTONEG_DONE: u16 = 1 << 5;
/// PHY Special Control/Status register.
const PSCSR: u8 = 31;

/// The link's speed and duplex as the PHY negotiated them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub struct Mode {
    /// 100 Mbit/s (else 10).
    pub fast: bool,
    /// Full duplex (else half).
    pub full_duplex: bool,
}

impl Mode {
    /// The mode of a PSCSR value (bits 4:2), if it names one.
    pub fn from_pscsr(pscsr: u16) -> Option<Mode> {
        match (pscsr >> 2) & 0b111 {
            0b001 => Some(Mode { fast: false, full_duplex: false }),
            0b101 => Some(Mode { fast: false, full_duplex: true }),
            0b010 => Some(Mode { fast: true, full_duplex: false }),
            0b110 => Some(Mode { fast: true, full_duplex: true }),
            _ => None,
        }
    }
}

/// The LAN8742A on the SMI bus `sm`.
pub struct Lan8742a<SM> {
    sm: SM,
    addr: u8,
    mode: Option<Mode>,
}

impl<SM: StationManagement> Lan8742a<SM> {
    /// The PHY on `sm`; its address is found at reset.
    pub fn new(sm: SM) -> Self {
        Self { sm, addr: 0, mode: None }
    }

    /// Sets the MAC's speed and duplex to the PHY's, with the transmitter and receiver
    /// stopped: embassy-stm32 0.6 has already started them (`eth/v1/mod.rs`, `new_inner`), and
    /// FES/DM changed under a running MAC would cut a frame in flight. The order is ST's
    /// stop/start sequence for this MAC (its STM32F4 HAL, `HAL_ETH_Stop` / `HAL_ETH_Start`,
    /// the only state in which `HAL_ETH_SetMACConfig` changes MACCR): stop the transmit DMA
    /// (ETH_DMAOMR ST), disable the receiver (ETH_MACCR RE), flush the transmit FIFO
    /// (ETH_DMAOMR FTF, which clears itself when done), disable the transmitter (TE); change
    /// FES and DM; then TE, RE and the transmit DMA on again. Registers: RM0090 §33.8.1 (MAC)
    /// and §33.8.4 (DMA). Each MACCR write is read back and followed by 10 µs, more than the
    /// four TX_CLK/RX_CLK cycles (1.6 µs at 10 Mbit/s) the MAC needs between two writes of one
    /// register (errata sheet ES0206, Ethernet: "successive write operations to the same
    /// register might not be fully taken into account"; the HAL waits the same way). The
    /// receive DMA keeps running on its descriptors.
    fn set_mac(&mut self, mode: Mode) {
        let mac = pac::ETH.ethernet_mac();
        let dma = pac::ETH.ethernet_dma();
        let settle = || {
            let _ = mac.maccr().read();
            embassy_time::block_for(Duration::from_micros(10));
        };
        dma.dmaomr().modify(|w| w.set_st(St::STOPPED));
        mac.maccr().modify(|w| w.set_re(false));
        settle();
        dma.dmaomr().modify(|w| w.set_ftf(Ftf::FLUSH));
        // FTF clears itself once the FIFO is flushed: bounded (a few TX_CLK cycles).
        for _ in 0..1000 {
            if dma.dmaomr().read().ftf() != Ftf::FLUSH {
                break;
            }
            embassy_time::block_for(Duration::from_micros(1));
        }
        mac.maccr().modify(|w| w.set_te(false));
        settle();
        mac.maccr().modify(|w| {
            w.set_fes(if mode.fast { Fes::FES100 } else { Fes::FES10 });
            w.set_dm(if mode.full_duplex { Dm::FULL_DUPLEX } else { Dm::HALF_DUPLEX });
        });
        settle();
        mac.maccr().modify(|w| {
            w.set_te(true);
            w.set_re(true);
        });
        settle();
        dma.dmaomr().modify(|w| w.set_st(St::STARTED));
        info!(
            "ethernet: link up, {} Mbit/s {} duplex",
            if mode.fast { 100 } else { 10 },
            if mode.full_duplex { "full" } else { "half" }
        );
        self.mode = Some(mode);
    }
}

impl<SM: StationManagement> Phy for Lan8742a<SM> {
    /// Finds the PHY (the Nucleo straps it to address 0; any address answers) and resets it,
    /// bounded: about 100 ms per address tried.
    fn phy_reset(&mut self) {
        for addr in 0..32u8 {
            self.sm.smi_write(addr, BCR, BCR_RESET);
            for _ in 0..100 {
                if self.sm.smi_read(addr, BCR) & BCR_RESET == 0 {
                    self.addr = addr;
                    return;
                }
                embassy_time::block_for(Duration::from_millis(1));
            }
        }
        error!("ethernet: the PHY does not answer on SMI");
    }

    fn phy_init(&mut self) {
        self.sm.smi_write(self.addr, BCR, BCR_AUTONEG);
    }

    fn poll_link(&mut self, cx: &mut Context) -> bool {
        // Poll the PHY twice a second (as GenericPhy does), not in a busy loop.
        let _ = pin!(Timer::after(Duration::from_millis(500))).poll(cx);
        let bsr = self.sm.smi_read(self.addr, BSR);
        let up = bsr & BSR_LINK != 0 && bsr & BSR_AUTONEG_DONE != 0;
        if !up {
            self.mode = None;
            return false;
        }
        if self.mode.is_none() {
            match Mode::from_pscsr(self.sm.smi_read(self.addr, PSCSR)) {
                Some(mode) => self.set_mac(mode),
                None => return false,
            }
        }
        true
    }
}
