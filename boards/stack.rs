// The stack's high-water mark (issue #39), for the boards on cortex-m-rt (the STM32 and QEMU
// boards include this file): the free stack is painted at start, and the mark is the lowest
// word no longer holding the paint. cortex-m-rt's link.x bounds the stack: `_stack_start` (its
// top, the initial MSP) down to `_stack_end` (the end of the statics, `.uninit`). Every
// interrupt handler (the main and realtime executors among them) runs on this one stack, and so
// does thread mode (the background executor) on the STM32 board; the QEMU board's thread mode
// has a stack of its own.

/// What the free stack is painted with.
const STACK_PAINT: u32 = 0x5AC3_A53C;

unsafe extern "C" {
    static mut _stack_end: u32;
    static _stack_start: u32;
}

/// Paints the stack from its bottom up to 256 bytes below the stack pointer (the frames in use
/// above it are left alone). The first thing the board does at start.
pub fn paint_stack() {
    let bottom = core::ptr::addr_of_mut!(_stack_end);
    let sp = cortex_m::register::msp::read() as usize;
    let words = (sp.saturating_sub(256) & !3).saturating_sub(bottom as usize) / 4;
    for i in 0..words {
        // SAFETY: every word from `_stack_end` up to below the stack pointer is stack no frame
        // uses (an interrupt's frame there is gone once it returns, before this goes on).
        unsafe { core::ptr::write_volatile(bottom.add(i), STACK_PAINT) };
    }
}

/// The main stack's bottom and top, as the linker places them.
pub fn main_stack() -> (usize, usize) {
    (core::ptr::addr_of!(_stack_end) as usize, core::ptr::addr_of!(_stack_start) as usize)
}

/// The most stack used since [`paint_stack`] (bytes from its top), and the stack's size.
pub fn stack_high_water() -> (usize, usize) {
    let (bottom, top) = main_stack();
    // SAFETY: the stack region the linker defines.
    (unsafe { high_water(bottom, top) }, top - bottom)
}

/// Paints a whole stack no code runs on yet, `bottom..top` (word-aligned addresses).
///
/// # Safety
/// `bottom..top` is a stack nothing uses yet.
#[allow(dead_code)]
pub unsafe fn paint(bottom: usize, top: usize) {
    for at in (bottom..top).step_by(4) {
        // SAFETY: a word of the unused stack (the caller's promise).
        unsafe { core::ptr::write_volatile(at as *mut u32, STACK_PAINT) };
    }
}

/// The most of the painted stack `bottom..top` used (bytes from its top).
///
/// # Safety
/// `bottom..top` is a stack region (word-aligned, readable).
pub unsafe fn high_water(bottom: usize, top: usize) -> usize {
    let mut at = bottom;
    // SAFETY: reads of words inside the stack region the caller names.
    while at < top && unsafe { core::ptr::read_volatile(at as *const u32) } == STACK_PAINT {
        at += 4;
    }
    top - at
}
