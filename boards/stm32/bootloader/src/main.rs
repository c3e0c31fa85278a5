//! The bootloader of the STM32 board (Nucleo-F429ZI, docs/update.md): at every start,
//! embassy-boot finishes or starts a swap (a marked update) or a revert (an update that did not
//! confirm itself), then starts the application in ACTIVE. The layout is the workspace's
//! memory.x (RM0090 §3.3, Table 6, the sectors of the 2 MiB part):
//! - bootloader: bank 1 sectors 0-1 (0x0800_0000, 32 KiB);
//! - ACTIVE: sectors 5-10 (0x0802_0000, 6 x 128 KiB);
//! - settings: bank 2 sectors 12-15 (0x0810_0000, untouched by updates);
//! - state: bank 2 sector 16 (0x0811_0000, 64 KiB), all of bank 2 region 2: the application
//!   erases it when it marks an update or a boot, and an erase in bank 1 would stall the code
//!   running there (RM0090 §3.6);
//! - DFU: bank 2 sectors 17-23 (0x0812_0000, 7 x 128 KiB: ACTIVE and one page for the swap).
//!
//! Each partition lies inside one of embassy-stm32's flash regions, whose erase size is that of
//! its sectors (64 KiB in bank 2 region 2, 128 KiB in region 3), so every erase is a whole
//! sector.
//!
//! Before a swap starts, the update partition must hold an image signed with the module's key:
//! the manifest the application wrote at the start of DFU's last page, and the digest of the
//! firmware it names, for the running image's model with a security counter not below its
//! (`remodaq_protocol::update::check_before_swap`). Otherwise the swap is
//! cancelled (the state marked booted) and the running image starts again.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("the STM32 board's bootloader runs on the Nucleo-F429ZI: see the README");
}

#[cfg(target_os = "none")]
mod boot {
    use core::cell::RefCell;

    use embassy_boot_stm32::{BlockingFirmwareState, BootLoader, BootLoaderConfig};
    use embassy_embedded_hal::flash::partition::BlockingPartition;
    use embassy_stm32::flash::{Flash, FlashBank, BANK2_REGION2, BANK2_REGION3, FLASH_BASE};
    use embassy_stm32::gpio::{Flex, Pull, Speed};
    use embassy_stm32::wdg::IndependentWatchdog;
    use embassy_sync::blocking_mutex::raw::NoopRawMutex;
    use embassy_sync::blocking_mutex::Mutex;
    use embedded_storage::nor_flash::NorFlash;
    use remodaq_protocol::update::{check_before_swap, BeforeSwap};

    // The watchdog's period, the application's (`WATCHDOG_TIMEOUT_US`).
    include!("../../watchdog.rs");

    // The key of this build (build.rs, boards/update-key.rs): `UPDATE_KEY`, `UPDATE_KEY_IS_TEST_KEY`.
    include!(concat!(env!("OUT_DIR"), "/update_key.rs"));

    /// ACTIVE: the start of bank 1 region 3 (sector 5), six sectors.
    const ACTIVE_OFFSET: u32 = 0;
    const ACTIVE_SIZE: u32 = 6 * 128 * 1024;
    /// DFU: all of bank 2 region 3 (sectors 17-23).
    const DFU_SIZE: u32 = 7 * 128 * 1024;
    /// State: sector 16, all of bank 2 region 2.
    const STATE_OFFSET: u32 = 0;
    const STATE_SIZE: u32 = 64 * 1024;
    /// Bank 1 region 3 starts at sector 5.
    const REGION3: u32 = 0x0802_0000;

    #[cortex_m_rt::entry]
    fn main() -> ! {
        // Reset clocks (HSI 16 MHz): programming and erasing work at any clock (RM0090 §3.5.1
        // relates the wait states to HCLK only).
        let p = embassy_stm32::init(Default::default());
        // Bank 2 (DFU) reads need PA12 held low with a pull-down on silicon before revision 3
        // (errata ES0206 2.2.11; embassy-stm32 0.6 refuses the read otherwise, `flash/f4.rs`),
        // as the application does (boards/stm32).
        let mut pa12 = Flex::new(p.PA12);
        pa12.set_low();
        pa12.set_as_input_output_pull(Speed::Low, Pull::Down);
        let layout = Flash::new_blocking(p.FLASH).into_blocking_regions();
        let active = Mutex::<NoopRawMutex, _>::new(RefCell::new(layout.bank1_region3));
        let dfu = Mutex::<NoopRawMutex, _>::new(RefCell::new(layout.bank2_region3));
        let state = Mutex::<NoopRawMutex, _>::new(RefCell::new(layout.bank2_region2));
        {
            // The manifest sits where the swap's scratch page starts: right after ACTIVE's size.
            let mut active = BlockingPartition::new(&active, ACTIVE_OFFSET, ACTIVE_SIZE);
            let mut dfu = BlockingPartition::new(&dfu, 0, DFU_SIZE);
            let mut state = BlockingPartition::new(&state, STATE_OFFSET, STATE_SIZE);
            match check_before_swap(&mut active, &mut dfu, &mut state, ACTIVE_SIZE, &UPDATE_KEY) {
                BeforeSwap::Nothing | BeforeSwap::Verified => {}
                // A refused image is never swapped in: if the cancel cannot be written (the
                // state would still ask for the swap), nothing starts; this bootloader runs
                // again and checks again.
                BeforeSwap::Refuse => {
                    if !cancel(state) {
                        cortex_m::peripheral::SCB::sys_reset()
                    }
                }
                // Nobody knows whether a swap is asked for: no swap, no start; again.
                BeforeSwap::Unreadable => cortex_m::peripheral::SCB::sys_reset(),
            }
        }
        let config = BootLoaderConfig {
            active: BlockingPartition::new(&active, ACTIVE_OFFSET, ACTIVE_SIZE),
            dfu: BlockingPartition::new(&dfu, 0, DFU_SIZE),
            state: BlockingPartition::new(&state, STATE_OFFSET, STATE_SIZE),
        };
        match BootLoader::try_prepare::<_, _, _, 2048>(config) {
            Ok(loader) => {
                // The watchdog, just before the jump (stm32 review R2): the application's
                // `embassy_stm32::init` waits without a bound for HSE, over-drive and the PLL
                // before the application starts the IWDG itself; started here, an image that
                // hangs there is reset, and a new one on trial then reverted. After the swap,
                // which may erase for longer than the period (RM0090 §3.5.1: up to 4 s per
                // 128 KiB sector). IWDG_PR and IWDG_RLR are written after 0x5555 to IWDG_KR,
                // then 0xCCCC starts it (RM0090 §21.3.2-21.3.4); the application writes the same
                // values. Frozen while a debugger halts the core, as the application does
                // (RM0090 §38.16.4, DBG_IWDG_STOP).
                embassy_stm32::pac::DBGMCU.apb1fzr().modify(|w| w.set_iwdg(true));
                IndependentWatchdog::new(p.IWDG, WATCHDOG_TIMEOUT_US).unleash();
                // SAFETY: ACTIVE holds an application linked at REGION3 (memory.x): its vector
                // table first; `load` points VTOR at it and jumps to its reset vector.
                unsafe { loader.load(REGION3) }
            }
            // A flash error: start again (a swap resumes where it stopped, docs/update.md).
            Err(_) => cortex_m::peripheral::SCB::sys_reset(),
        }
    }

    const _: () = assert!(FLASH_BASE as u32 + 0x2_0000 == REGION3);

    // The layout as both linker scripts give it (build.rs: `APP_*` from the application's
    // memory.x, `BOOT_*` from this bootloader's), tied to the constants above and to embassy's
    // regions (stm32 review N2): a change in one place that the others do not follow stops the
    // build.
    include!(concat!(env!("OUT_DIR"), "/layout.rs"));
    const _: () = assert!(
        APP_FLASH_ORIGIN == REGION3 && BOOT_ACTIVE_START == REGION3,
        "ACTIVE does not start at bank 1 region 3"
    );
    const _: () = assert!(
        APP_FLASH_LENGTH == ACTIVE_SIZE && BOOT_ACTIVE_END - BOOT_ACTIVE_START == ACTIVE_SIZE,
        "ACTIVE's size differs between memory.x, the bootloader's memory.x and ACTIVE_SIZE"
    );
    const _: () = assert!(
        APP_DFU_START == BOOT_DFU_START && APP_DFU_END == BOOT_DFU_END && APP_DFU_END - APP_DFU_START == DFU_SIZE,
        "DFU differs between memory.x, the bootloader's memory.x and DFU_SIZE"
    );
    const _: () = assert!(
        APP_STATE_START == BOOT_STATE_START
            && APP_STATE_END == BOOT_STATE_END
            && APP_STATE_END - APP_STATE_START == STATE_SIZE,
        "the state differs between memory.x, the bootloader's memory.x and STATE_SIZE"
    );
    // embassy's regions: DFU is all of bank 2 region 3, the state all of bank 2 region 2; bank 2
    // starts 1 MiB into the flash of a 2 MiB part (RM0090 §3.3, Table 6).
    const BANK2: u32 = FLASH_BASE as u32 + 0x10_0000;
    const _: () = assert!(
        matches!(BANK2_REGION3.bank, FlashBank::Bank2)
            && BANK2 + BANK2_REGION3.offset == APP_DFU_START
            && BANK2_REGION3.size == DFU_SIZE,
        "DFU is not bank 2 region 3"
    );
    const _: () = assert!(BANK2 + BANK2_REGION2.offset == APP_STATE_START, "the state is not bank 2 region 2");
    // embassy-boot's swap: DFU holds ACTIVE and one page more (docs/update.md).
    const _: () = assert!(DFU_SIZE >= ACTIVE_SIZE + 128 * 1024, "DFU is smaller than ACTIVE and one page");
    // The state: bank 2 sector 16, 0x0811_0000 (64 KiB into bank 2), as memory.x says.
    const _: () = assert!(
        matches!(BANK2_REGION2.bank, FlashBank::Bank2)
            && BANK2_REGION2.offset == 0x1_0000
            && BANK2_REGION2.size == STATE_SIZE
    );

    // Never the repository's test key (public secret half) unless asked (docs/security.md).
    const _: () = assert!(
        cfg!(feature = "test-update-key") || !UPDATE_KEY_IS_TEST_KEY,
        "this bootloader would trust the repository's TEST update key: build it with REMODAQ_UPDATE_KEY, \
         or ask for the test key explicitly (feature test-update-key, test builds only)"
    );

    /// Cancels a swap: the state marked booted (embassy-boot's own marking). Whether the marking
    /// was written: embassy-boot writes "progress invalid" first, so a failure there leaves
    /// the swap asked for and not started (stm32 review D2), and the caller must not go on.
    fn cancel<S: NorFlash>(state: S) -> bool {
        #[repr(align(32))]
        struct Aligned([u8; 32]);
        let mut aligned = Aligned([0; 32]);
        const { assert!(S::WRITE_SIZE <= 32) };
        BlockingFirmwareState::new(state, &mut aligned.0[..S::WRITE_SIZE]).mark_booted().is_ok()
    }

    #[panic_handler]
    fn panic(_: &core::panic::PanicInfo) -> ! {
        cortex_m::peripheral::SCB::sys_reset()
    }
}
