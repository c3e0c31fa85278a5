//! Flash wear of the settings (docs/security.md, "Flash wear"): the 8350's largest settings
//! record committed again and again into the boards' settings region (64 KiB in four 16 KiB
//! sectors, RM0090 §3.3 Table 6: bank 2 sectors 12-15), counting the erases of each sector.
//! From that count and the module's commit budget, the worst case over 10 years must stay
//! within the 10 000 erase cycles the STM32F429 datasheet (DS9405 Table 42, "Flash memory
//! endurance", N_END) guarantees per sector.

use embedded_storage_async::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use futures_executor::block_on;
use remodaq_8350::pulse::PulseConfig;
use remodaq_8350::settings::Settings;
use remodaq_shared::access::{AllowList, Network};
use remodaq_shared::module::{ADMIN_BURST, ADMIN_REFILL_MS, COMMIT_BURST, COMMIT_REFILL_MS};
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::{Schema, SettingsStore};

const SECTOR: usize = 16 * 1024;
const SIZE: usize = 4 * SECTOR;

/// A RAM flash that counts the erases of each sector.
struct Counting {
    flash: RamFlash<SIZE, SECTOR>,
    erases: [u64; SIZE / SECTOR],
}

impl ErrorType for Counting {
    type Error = <RamFlash<SIZE, SECTOR> as ErrorType>::Error;
}

impl ReadNorFlash for Counting {
    const READ_SIZE: usize = <RamFlash<SIZE, SECTOR> as ReadNorFlash>::READ_SIZE;
    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.flash.read(offset, bytes).await
    }
    fn capacity(&self) -> usize {
        SIZE
    }
}

impl NorFlash for Counting {
    const WRITE_SIZE: usize = <RamFlash<SIZE, SECTOR> as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = SECTOR;
    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        for sector in (from as usize / SECTOR)..(to as usize).div_ceil(SECTOR) {
            self.erases[sector] += 1;
        }
        self.flash.erase(from, to).await
    }
    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.flash.write(offset, bytes).await
    }
}

/// The largest record: every field present, the widest values, a full allow-list.
fn largest(n: u32) -> Settings {
    let mut s = Settings::defaults();
    s.pulses = [PulseConfig { low: u32::MAX - n, high: u32::MAX, count: u32::MAX }; 6];
    let nets: Vec<Network> = (0..4u8).map(|i| Network::new([10, i, 0, 0], 16).unwrap()).collect();
    s.allow = AllowList::of(&nets).unwrap();
    s
}

#[test]
fn ten_years_at_the_budgets_worst_rate_stay_within_10_000_erase_cycles() {
    let flash = Counting { flash: RamFlash::new(), erases: [0; 4] };
    let mut store =
        block_on(SettingsStore::open(flash, const { SettingsStore::<Counting, Settings>::config(0..SIZE as u32) }));
    const COMMITS: u64 = 4000;
    for n in 0..COMMITS {
        block_on(store.commit(largest(n as u32))).expect("commit");
    }
    let erases = store.into_flash().erases;
    let most = *erases.iter().max().unwrap();
    assert!(most > 0, "the test wrapped the store: {erases:?}");
    // Commits per erase of the most-worn sector.
    let commits_per_erase = COMMITS as f64 / most as f64;
    // The budgets' worst rate, both spent as fast as they allow: each its burst, then one
    // commit every refill, for 10 years (Modbus writes; authenticated changes under any
    // credential, the public factory password included). A restart renews neither
    // (shared/tests/settings_store.rs).
    let ten_years_ms = 10.0 * 365.25 * 24.0 * 3600.0 * 1000.0;
    let writes = f64::from(COMMIT_BURST) + ten_years_ms / COMMIT_REFILL_MS as f64;
    let admin = f64::from(ADMIN_BURST) + ten_years_ms / ADMIN_REFILL_MS as f64;
    let worst = writes + admin;
    let cycles = worst / commits_per_erase;
    eprintln!(
        "erases per sector after {COMMITS} commits: {erases:?}: {commits_per_erase:.1} commits per erase; \
         10 years at the budgets' worst rate: {writes:.0} + {admin:.0} = {worst:.0} commits, {cycles:.0} erase cycles of the most-worn sector"
    );
    assert!(cycles <= 10_000.0, "{cycles:.0} erase cycles in 10 years");
}
