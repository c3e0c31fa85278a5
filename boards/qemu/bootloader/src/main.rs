//! The bootloader of the QEMU board (`-kernel` image): at every start, embassy-boot finishes or
//! starts a swap (a marked update) or a revert (an update that did not confirm itself), then the
//! application in ACTIVE runs. At QEMU's power-on the code memory is all zeros: the bootloader
//! then copies the first application from SEED into ACTIVE and erases the state and update
//! partitions, as a factory would program the module's flash. The flash layout is in
//! `../layout.x`; docs/update.md explains it. As on the STM32, a swap starts only for an image
//! signed with the key, for the running image's model, with a counter not below its
//! (`remodaq_protocol::update::check_before_swap`); otherwise it is
//! cancelled and the running image starts again.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("the QEMU board's bootloader runs under QEMU: see scripts/qemu");
}

#[cfg(target_os = "none")]
mod boot {
    use embassy_boot::{BlockingFirmwareState, BootLoader, BootLoaderConfig};
    use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};
    use remodaq_protocol::update::{check_before_swap, BeforeSwap};

    // The key of this build (build.rs, boards/update-key.rs): `UPDATE_KEY`, `UPDATE_KEY_IS_TEST_KEY`.
    include!(concat!(env!("OUT_DIR"), "/update_key.rs"));
    use remodaq_ram_nor::RamNor;

    /// The swap's page: as the STM32F429's 128 KiB sectors of ACTIVE and DFU.
    const PAGE: usize = 128 * 1024;
    /// The state partition's erase page (bank 2 sector 16, 64 KiB, on the STM32).
    const STATE_PAGE: usize = 64 * 1024;

    unsafe extern "C" {
        static mut __bootloader_state_start: u8;
        static __bootloader_state_end: u8;
        static mut __bootloader_active_start: u8;
        static __bootloader_active_end: u8;
        static mut __bootloader_dfu_start: u8;
        static __bootloader_dfu_end: u8;
        static mut __seed_start: u8;
    }

    fn region<const ERASE: usize>(start: *mut u8, end: *const u8) -> RamNor<ERASE> {
        // SAFETY: the linker symbols bound disjoint regions of QEMU's code memory (layout.x);
        // each is taken once, here, and the bootloader is the only code running.
        unsafe { RamNor::new(start, end as usize - start as usize) }
    }

    #[cortex_m_rt::entry]
    fn main() -> ! {
        use core::ptr::{addr_of, addr_of_mut};
        let mut state = region::<STATE_PAGE>(addr_of_mut!(__bootloader_state_start), addr_of!(__bootloader_state_end));
        let mut active = region::<PAGE>(addr_of_mut!(__bootloader_active_start), addr_of!(__bootloader_active_end));
        let mut dfu = region::<PAGE>(addr_of_mut!(__bootloader_dfu_start), addr_of!(__bootloader_dfu_end));
        let size = active.capacity();
        if active.untouched() {
            // Power-on: program ACTIVE from SEED; erased state and update partitions.
            let seed_end = (addr_of!(__seed_start) as usize + size) as *const u8;
            let mut seed = region::<PAGE>(addr_of_mut!(__seed_start), seed_end);
            let mut buf = [0u8; 1024];
            let mut ok = active.erase(0, size as u32).is_ok();
            for at in (0..size as u32).step_by(buf.len()) {
                ok = ok && seed.read(at, &mut buf).is_ok() && active.write(at, &buf).is_ok();
            }
            ok = ok && dfu.erase(0, dfu.capacity() as u32).is_ok() && state.erase(0, state.capacity() as u32).is_ok();
            if !ok {
                fail("programming the first application failed");
            }
        }
        // The manifest sits where the swap's scratch page starts: right after ACTIVE's size.
        match check_before_swap(&mut active, &mut dfu, &mut state, size as u32, &UPDATE_KEY) {
            BeforeSwap::Nothing | BeforeSwap::Verified => {}
            BeforeSwap::Refuse => {
                cortex_m_semihosting::hprintln!(
                    "bootloader: the marked update is not signed with the key, or not for this model and counter: not swapped"
                );
                let mut word = [0u8; 4];
                if BlockingFirmwareState::new(&mut state, &mut word).mark_booted().is_err() {
                    fail("cancelling the swap failed");
                }
            }
            // Fail closed: no swap and no start when nobody knows whether one is asked for.
            BeforeSwap::Unreadable => fail("the bootloader's state cannot be read"),
        }
        let mut aligned = [0u8; 1024];
        let config = BootLoaderConfig { active: &mut active, dfu: &mut dfu, state: &mut state };
        if BootLoader::new(config).prepare_boot(&mut aligned).is_err() {
            fail("the swap or revert failed");
        }
        let vectors = addr_of!(__bootloader_active_start) as *const u32;
        // SAFETY: ACTIVE holds an application linked there (its vector table first); VTOR takes
        // its address so its interrupts go to its own handlers; nothing of the bootloader is
        // used after the jump.
        unsafe {
            (*cortex_m::peripheral::SCB::PTR).vtor.write(vectors as u32);
            cortex_m::asm::bootload(vectors)
        }
    }

    fn fail(why: &str) -> ! {
        stop(format_args!("bootloader: {}", why))
    }

    /// Prints over semihosting and ends QEMU with a failure.
    fn stop(message: core::fmt::Arguments<'_>) -> ! {
        cortex_m_semihosting::hprintln!("{}", message);
        cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
        loop {
            cortex_m::asm::wfi();
        }
    }

    #[panic_handler]
    fn panic(info: &core::panic::PanicInfo) -> ! {
        stop(format_args!("bootloader panic: {}", info))
    }
}
