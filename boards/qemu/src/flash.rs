//! The "flash" of the QEMU board: regions of QEMU's code memory (writable RAM) driven as NOR
//! flash by `remodaq-ram-nor`, at the addresses of the board's layout (`layout.x`): the
//! settings (64 KiB in 16 KiB pages, as the STM32's sectors 12-15), and the bootloader's update
//! (DFU, 128 KiB pages) and state (one 64 KiB page) partitions. Each goes through the firmware's
//! flash controller lock, as on the STM32 (`remodaq_shared::flash`).

use remodaq_ram_nor::RamNor;
use remodaq_shared::flash::{Serialized, CONTROLLER};

/// Size of the settings region.
pub const SIZE: usize = 64 * 1024;
/// Erase page of the settings (as the STM32's 16 KiB sectors).
pub const PAGE: usize = 16 * 1024;
/// Erase page of the update partition (the STM32's 128 KiB sectors).
pub const DFU_PAGE: usize = 128 * 1024;

/// Erase page of the bootloader's state (the STM32's 64 KiB sector 16).
pub const STATE_PAGE: usize = 64 * 1024;

/// The settings region.
pub type SettingsFlash = Serialized<RamNor<PAGE>>;
/// The update (DFU) partition.
pub type DfuFlash = Serialized<RamNor<DFU_PAGE>>;
/// The bootloader's state partition.
pub type StateFlash = Serialized<RamNor<STATE_PAGE>>;

unsafe extern "C" {
    static mut __settings_start: u8;
    static __settings_end: u8;
    static mut __bootloader_dfu_start: u8;
    static __bootloader_dfu_end: u8;
    static mut __bootloader_state_start: u8;
    static __bootloader_state_end: u8;
}

fn region<const ERASE: usize>(start: *mut u8, end: *const u8) -> Serialized<RamNor<ERASE>> {
    // SAFETY: the linker symbols bound disjoint regions of QEMU's code memory outside the
    // application's own (layout.x); `Regions::take` hands each out once.
    Serialized::new(unsafe { RamNor::new(start, end as usize - start as usize) }, &CONTROLLER)
}

/// The board's flash regions, each owned once.
pub struct Regions {
    /// The settings.
    pub settings: SettingsFlash,
    /// The update partition.
    pub dfu: DfuFlash,
    /// The bootloader's state.
    pub state: StateFlash,
}

impl Regions {
    /// The regions (called once, from the board's `init`).
    pub(crate) fn take() -> Self {
        use core::ptr::{addr_of, addr_of_mut};
        let (start, end) = (addr_of_mut!(__settings_start), addr_of!(__settings_end));
        // SAFETY: as in `region`: the settings region of layout.x, handed out once, here.
        let mut settings = unsafe { RamNor::<PAGE>::new(start, end as usize - start as usize) };
        // QEMU's memory reads zero at its power-on, where a new module's flash reads erased
        // (0xFF): erased here, so that the settings store finds a new module, not a damaged
        // store (which it would load locked: docs/security.md, "Migration").
        if settings.untouched() {
            settings.erase_all();
        }
        Self {
            settings: Serialized::new(settings, &CONTROLLER),
            dfu: region(addr_of_mut!(__bootloader_dfu_start), addr_of!(__bootloader_dfu_end)),
            state: region(addr_of_mut!(__bootloader_state_start), addr_of!(__bootloader_state_end)),
        }
    }
}
