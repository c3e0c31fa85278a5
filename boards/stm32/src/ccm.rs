//! The CCM: 64 KiB of data RAM at 0x1000_0000 on the Cortex-M4's D-bus only (RM0090 §2.3, the
//! memory map; §2.1.1, Figure 1: no DMA reaches it). Its clock is on from reset (RM0090
//! §6.3.10, RCC_AHB1ENR CCMDATARAMEN of the F42x/F43x, reset value 1), but a bootloader may have switched it
//! off (ST's ROM bootloader writes 0 to RCC_AHB1ENR on exit: ST community, "Unexpected CCM
//! state after using the STM32F4 boot loader"), so [`load`] switches it on first. Two output
//! sections of memory.x use it:
//! - `.ccmdata`: statics only the CPU uses (`#[link_section = ".ccmdata.NAME"]`), whose initial
//!   values the linker keeps in flash as it does .data's; [`load`] copies them at start;
//! - `.ccmbss`: the services' task pools (all zeros at first, as .bss), which [`load`] zeroes;
//! - `.ccmram`: words kept across a reset, neither loaded nor zeroed.
//!
//! What a DMA touches stays in SRAM, checked at link time (memory.x's ASSERTs on the statics
//! named `REMODAQ_DMA_*`).

unsafe extern "C" {
    static mut __sccmbss: u32;
    static mut __eccmbss: u32;
    static mut __sccmdata: u32;
    static mut __eccmdata: u32;
    static __siccmdata: u32;
}

/// Copies `.ccmdata`'s initial values from flash and zeroes `.ccmbss`. The first thing the
/// board does at start, before any static there is used (the task pools there are used when
/// their tasks are spawned, after the board's `init`).
pub(crate) fn load() {
    // The CCM's clock (RM0090 §6.3.10, RCC_AHB1ENR bit 20 CCMDATARAMEN), then a DSB before
    // the first access: errata ES0206, "Delay after an RCC peripheral clock enabling" (a
    // dummy read was shown not to be enough on the F407/F429: efton.sk STM32 gotcha 183).
    embassy_stm32::pac::RCC.ahb1enr().modify(|w| w.set_ccmdataramen(true));
    cortex_m::asm::dsb();
    // SAFETY: the linker's symbols bound `.ccmdata` in the CCM and its load image in flash,
    // both word-aligned (memory.x: ALIGN(4) at each end); nothing has used a static there yet
    // (this runs first in `init`); volatile word copies, so the compiler cannot move them.
    unsafe {
        let to = core::ptr::addr_of_mut!(__sccmdata);
        let end = core::ptr::addr_of_mut!(__eccmdata);
        let from = core::ptr::addr_of!(__siccmdata);
        let words = (end as usize - to as usize) / 4;
        for i in 0..words {
            core::ptr::write_volatile(to.add(i), core::ptr::read_volatile(from.add(i)));
        }
    }
    // SAFETY: as above, for `.ccmbss` (word-aligned at both ends; nothing there used yet).
    unsafe {
        let to = core::ptr::addr_of_mut!(__sccmbss);
        let end = core::ptr::addr_of_mut!(__eccmbss);
        let words = (end as usize - to as usize) / 4;
        for i in 0..words {
            core::ptr::write_volatile(to.add(i), 0);
        }
    }
}
