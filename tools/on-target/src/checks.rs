//! The checks, and how they report.

use core::sync::atomic::{AtomicU32, Ordering};

use embassy_executor::Spawner;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer};
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_8318::settings::Settings;
use remodaq_shared::app::{spawn, spawn_send};
use remodaq_shared::board::Board;
use remodaq_shared::settings::SettingsStore;

#[cfg(feature = "board-qemu")]
use remodaq_board_qemu::QemuBoard as B;
#[cfg(not(feature = "board-qemu"))]
use remodaq_board_stm32::Stm32Board as B;

/// Prints a line: over RTT (defmt) on the STM32, over semihosting under QEMU.
macro_rules! say {
    ($($arg:tt)*) => {{
        #[cfg(feature = "board-qemu")]
        cortex_m_semihosting::hprintln!($($arg)*);
        #[cfg(not(feature = "board-qemu"))]
        defmt::println!($($arg)*);
    }};
}

/// Passed, failed and not applicable checks.
struct Report {
    passed: u32,
    failed: u32,
    not_applicable: u32,
}

/// What a check that ran without failing showed.
enum Verdict {
    Passed,
    /// This board cannot show what the check is for (why): never counted as passed.
    NotApplicable(&'static str),
}

impl Report {
    fn check(&mut self, name: &str, result: Result<Verdict, &'static str>) {
        match result {
            Ok(Verdict::Passed) => {
                self.passed += 1;
                say!("on-target {} ... ok", name);
            }
            Ok(Verdict::NotApplicable(why)) => {
                self.not_applicable += 1;
                say!("on-target {} ... not applicable here: {}", name, why);
            }
            Err(why) => {
                self.failed += 1;
                say!("on-target {} ... FAILED: {}", name, why);
            }
        }
    }
}

/// A check that ran without failing: passed.
fn passed(result: Result<(), &'static str>) -> Result<Verdict, &'static str> {
    result.map(|()| Verdict::Passed)
}

/// The longest gap between two ticks of the ticker task, ms, since the last reset.
static MAX_GAP_MS: AtomicU32 = AtomicU32::new(0);
/// The ticker task's period.
const TICK: Duration = Duration::from_millis(50);
/// The watchdog's window on the STM32 board (how late a task may be while it is fed).
const ALIVE_WINDOW_MS: u32 = 3000;
/// The datasheet's longest 16 KiB sector erase at x32 parallelism (DS9405, "Flash memory
/// programming", tERASE16KB: 500 ms at x32, 800 ms at x8), which the STM32 board erases at
/// (boards/stm32/src/x32.rs).
const ERASE_MAX_MS: u64 = 500;

/// Ticks, records the longest gap, and beats the application's heartbeat (so the board's own
/// watchdog, where there is one, runs its real policy through the tests).
#[embassy_executor::task]
async fn ticker() -> ! {
    let mut last = Instant::now();
    loop {
        Timer::after(TICK).await;
        let now = Instant::now();
        MAX_GAP_MS.fetch_max((now - last).as_millis() as u32, Ordering::Relaxed);
        last = now;
        B::app_alive();
    }
}

/// Runs every check, prints the summary and exits with its status.
pub async fn run(spawner: Spawner) {
    let mut report = Report { passed: 0, failed: 0, not_applicable: 0 };
    let (mut board, flash, resources) = B::init(spawner);
    spawn(spawner, ticker(), "ticker");
    say!("on-target: reset cause {}", board.reset_cause() as u16);
    // First: a bank-2 erase must not stall the code running from bank 1 (RM0090 §3.6; an ST
    // forum thread reports a stall on this chip), which the update and settings designs rely on
    // (stm32 review R3; README, "On a Nucleo").
    match board.boot_partitions() {
        Some((mut dfu, mut state)) => {
            report.check(
                "update partitions: the bootloader's state reads Boot, a DFU sector erased, written, read back",
                passed(update_partitions(&mut dfu, &mut state).await),
            );
            spawn(spawner, fine_ticker(), "fine ticker");
            report.check(
                "bootloader state: marked updated then booted, the executor never stalls over 5 ms",
                state_marks(&mut state).await,
            );
        }
        None => report.check("update partitions", Err("the board gives no update partitions")),
    }

    let (mut flash, original) = open_store(flash).await;
    report.check("erase: every settings sector, the executor keeps running", erase(&mut flash).await);
    report.check(
        "settings store: the saved settings written back, and a change, reload",
        passed(settings_store(flash, original).await),
    );
    report.check("time base: a 1 s timer", time_base().await);
    report.check(
        "realtime executor: its 1 ms ticker keeps time while the main executor checks ed25519 signatures",
        realtime(spawner).await,
    );
    report.check(
        "background executor: the main executor's 1 ms ticker keeps time while the background one (MQTT's and its TLS's) checks ed25519 signatures",
        background().await,
    );
    board_checks(&mut report, spawner, board, resources).await;
    report.check("stack: its high-water mark after every check, within the stack with 1 KiB to spare", stack_mark());

    say!("on-target: {} passed, {} failed, {} not applicable", report.passed, report.failed, report.not_applicable);
    exit(report.failed == 0);
}

/// The bootloader's partitions (docs/update.md), through embassy-boot's updater as the update
/// service uses them: the state reads Boot (this image was started by the bootloader and is
/// confirmed, or the partition is erased), and the first DFU sector takes a pattern and reads it
/// back. Nothing is marked: the next start boots this image again.
async fn update_partitions<D: NorFlash, S: NorFlash>(dfu: D, state: S) -> Result<(), &'static str> {
    // The state buffer is STATE::WRITE_SIZE long (at most 32 bytes on the targets).
    let mut aligned = [0u8; 32];
    let mut updater = embassy_boot::FirmwareUpdater::new(
        embassy_boot::FirmwareUpdaterConfig { dfu, state },
        &mut aligned[..S::WRITE_SIZE.min(32)],
    );
    match updater.get_state().await {
        Ok(embassy_boot::State::Boot) => {}
        Ok(_) => return Err("the bootloader's state is not Boot"),
        Err(_) => return Err("the bootloader's state cannot be read"),
    }
    let pattern: [u8; 256] = core::array::from_fn(|i| (i as u8).wrapping_mul(7) ^ 0x5A);
    let start = Instant::now();
    updater.write_firmware(0, &pattern).await.map_err(|_| "erasing or writing the first DFU sector failed")?;
    say!("on-target: first DFU sector erased and written in {} ms", start.elapsed().as_millis());
    let mut back = [0u8; 256];
    updater.read_dfu(0, &mut back).await.map_err(|_| "reading the DFU back failed")?;
    if back != pattern {
        return Err("the DFU did not read back what was written");
    }
    Ok(())
}

/// The longest gap between two wakes of the fine ticker, µs, since the last reset.
static MAX_FINE_GAP_US: AtomicU32 = AtomicU32::new(0);
/// Ends the fine ticker (after its check, so its 2 kHz wakes do not load the later ones).
static FINE_TICKER_STOP: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);
/// The fine ticker's period.
const FINE_TICK: Duration = Duration::from_micros(500);
/// The longest executor stall allowed while the bootloader's state is marked (issue #21).
const MARK_STALL_MAX_US: u64 = 5_000;

/// Wakes every [`FINE_TICK`] and records the longest gap: a stall of the executor (or of the
/// CPU, as an erase of the bank the code runs from would cause) shows as a longer one.
#[embassy_executor::task]
async fn fine_ticker() {
    let mut last = Instant::now();
    while !FINE_TICKER_STOP.load(Ordering::Relaxed) {
        Timer::after(FINE_TICK).await;
        let now = Instant::now();
        MAX_FINE_GAP_US.fetch_max((now - last).as_micros() as u32, Ordering::Relaxed);
        last = now;
    }
}

/// Marks the bootloader's state updated, then booted, as an update session and the next start
/// do (each erases the state's sector, in bank 2: docs/update.md), and measures the executor's
/// longest stall meanwhile. An update marked here is never swapped: it is marked booted at
/// once, and the bootloader refuses a swap without a signed manifest anyway.
async fn state_marks<S: NorFlash>(state: S) -> Result<Verdict, &'static str> {
    let mut aligned = [0u8; 32];
    let mut firmware_state = embassy_boot::FirmwareState::new(state, &mut aligned[..S::WRITE_SIZE.min(32)]);
    Timer::after(FINE_TICK * 4).await;
    MAX_FINE_GAP_US.store(0, Ordering::Relaxed);
    let start = Instant::now();
    let updated = firmware_state.mark_updated().await;
    let booted = firmware_state.mark_booted().await;
    let took = start.elapsed().as_millis();
    Timer::after(FINE_TICK * 4).await;
    FINE_TICKER_STOP.store(true, Ordering::Relaxed);
    updated.map_err(|_| "marking the state updated failed")?;
    booted.map_err(|_| "marking the state booted failed")?;
    let stall_us = u64::from(MAX_FINE_GAP_US.load(Ordering::Relaxed)).saturating_sub(FINE_TICK.as_micros());
    say!("on-target: state marked updated and booted in {} ms; longest executor stall {} us", took, stall_us);
    if cfg!(feature = "board-qemu") {
        return Ok(Verdict::NotApplicable(
            "the QEMU board's flash is RAM (an erase takes no time) and its timers wake at 1 kHz: no stall to measure",
        ));
    }
    if stall_us > MARK_STALL_MAX_US {
        return Err("the executor stalled over 5 ms while the state was marked");
    }
    Ok(Verdict::Passed)
}

/// The settings region of the board.
type Flash = <B as Board>::Flash;

const fn config() -> sequential_storage::map::MapConfig<Flash> {
    SettingsStore::<Flash, Settings>::config(0..<B as Board>::SETTINGS_SIZE)
}

/// Opens the store to save the settings in force.
async fn open_store(flash: Flash) -> (Flash, Settings) {
    let store = SettingsStore::<Flash, Settings>::open(flash, const { config() }).await;
    let original = *store.get();
    (store.into_flash(), original)
}

/// Erases every sector of the settings region, timing each, while the ticker runs.
async fn erase(flash: &mut Flash) -> Result<Verdict, &'static str> {
    MAX_GAP_MS.store(0, Ordering::Relaxed);
    let sector = Flash::ERASE_SIZE as u32;
    let mut longest = 0;
    for from in (0..<B as Board>::SETTINGS_SIZE).step_by(sector as usize) {
        let start = Instant::now();
        flash.erase(from, from + sector).await.map_err(|_| "an erase failed")?;
        longest = longest.max(start.elapsed().as_millis());
    }
    Timer::after(TICK * 2).await;
    let gap = MAX_GAP_MS.load(Ordering::Relaxed);
    say!("on-target: longest sector erase {} ms, longest gap between ticks {} ms", longest, gap);
    if longest > ERASE_MAX_MS {
        return Err("a sector erase took longer than the datasheet's maximum");
    }
    if gap >= ALIVE_WINDOW_MS {
        return Err("the executor stalled for the watchdog's window during an erase");
    }
    if cfg!(feature = "board-qemu") {
        return Ok(Verdict::NotApplicable("the QEMU board's flash is RAM: an erase takes no time and stalls nothing"));
    }
    Ok(Verdict::Passed)
}

/// Writes the saved settings back to the blank store, then a change, reopening after each.
async fn settings_store(flash: Flash, original: Settings) -> Result<(), &'static str> {
    let mut store = SettingsStore::<Flash, Settings>::open(flash, const { config() }).await;
    store.commit(original).await.map_err(|_| "writing the saved settings back failed")?;
    let mut store = SettingsStore::<Flash, Settings>::open(store.into_flash(), const { config() }).await;
    if *store.get() != original {
        return Err("the saved settings did not load back");
    }
    let changed = Settings {
        input_type: if original.input_type == 0x0E { 0x0F } else { 0x0E },
        enable_mask: original.enable_mask ^ 0x5A,
        ..original
    };
    store.commit(changed).await.map_err(|_| "a commit failed")?;
    let mut store = SettingsStore::<Flash, Settings>::open(store.into_flash(), const { config() }).await;
    if *store.get() != changed {
        return Err("a committed change did not load back");
    }
    store.commit(original).await.map_err(|_| "restoring the settings failed")?;
    let store = SettingsStore::<Flash, Settings>::open(store.into_flash(), const { config() }).await;
    if *store.get() != original {
        return Err("the restored settings did not load back");
    }
    Ok(())
}

/// A 1 s timer lasts 1 s of the time base, and (STM32) of the core clock: the DWT cycle counter
/// at 180 MHz from the HSE.
async fn time_base() -> Result<Verdict, &'static str> {
    #[cfg(not(feature = "board-qemu"))]
    let cycles_before = {
        // SAFETY: the DCB and DWT are used by this check only (the board takes no core
        // peripheral but through embassy, which leaves these alone); enabling the cycle counter
        // has no other effect.
        let mut core = unsafe { cortex_m::Peripherals::steal() };
        core.DCB.enable_trace();
        core.DWT.enable_cycle_counter();
        cortex_m::peripheral::DWT::cycle_count()
    };
    let start = Instant::now();
    Timer::after(Duration::from_secs(1)).await;
    let elapsed = start.elapsed();
    if elapsed < Duration::from_secs(1) || elapsed > Duration::from_millis(1050) {
        return Err("a 1 s timer did not last 1 s of the time base");
    }
    #[cfg(not(feature = "board-qemu"))]
    {
        let cycles = cortex_m::peripheral::DWT::cycle_count().wrapping_sub(cycles_before);
        let expected = 180_000_000.0 * elapsed.as_micros() as f64 / 1e6;
        let ppm = (f64::from(cycles) - expected) / expected * 1e6;
        say!("on-target: time base against the core clock: {} ppm", ppm as i32);
        if !(-50.0..=50.0).contains(&ppm) {
            return Err("the time base drifts from the core clock by more than 50 ppm");
        }
    }
    if cfg!(feature = "board-qemu") {
        // The timer and the measure are the same FPGAIO counter: no independent clock to compare with.
        return Ok(Verdict::NotApplicable(
            "no clock independent of the time base under QEMU (the timer and its measure are both the FPGAIO counter)",
        ));
    }
    Ok(Verdict::Passed)
}

/// The realtime ticker's longest gap between two wakes, µs, and its wakes, while measuring.
static REALTIME_GAP_US: AtomicU32 = AtomicU32::new(0);
static REALTIME_WAKES: AtomicU32 = AtomicU32::new(0);
static REALTIME_MEASURING: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);
/// The realtime ticker's period.
const REALTIME_TICK: Duration = Duration::from_millis(1);
/// How long an executor computes without yielding in [`busy`].
const BUSY: Duration = Duration::from_millis(100);
/// The 8350's margin: its output ring holds 6.4 ms more than the chunk it waits room for.
const RING_SLACK_US: u32 = 6_400;

/// On the board's realtime executor (`Board::realtime`, where the 8350's I/O loop runs).
#[embassy_executor::task]
async fn realtime_ticker() -> ! {
    let mut ticker = embassy_time::Ticker::every(REALTIME_TICK);
    let mut last = Instant::now();
    loop {
        ticker.next().await;
        let now = Instant::now();
        if REALTIME_MEASURING.load(Ordering::Relaxed) {
            REALTIME_GAP_US.fetch_max((now - last).as_micros() as u32, Ordering::Relaxed);
            REALTIME_WAKES.fetch_add(1, Ordering::Relaxed);
        }
        last = now;
    }
}

/// The realtime executor preempts the main one: its 1 ms ticker keeps time ([`kept_time`]).
async fn realtime(spawner: Spawner) -> Result<Verdict, &'static str> {
    spawn_send(B::realtime(spawner), realtime_ticker(), "realtime ticker");
    Timer::after(Duration::from_millis(20)).await;
    REALTIME_MEASURING.store(true, Ordering::Relaxed);
    let (checks, busy) = busy();
    REALTIME_MEASURING.store(false, Ordering::Relaxed);
    let (gap, wakes) = (REALTIME_GAP_US.load(Ordering::Relaxed), REALTIME_WAKES.load(Ordering::Relaxed));
    say!(
        "on-target: the main executor busy {} ms ({} ed25519 checks, {} us each); the realtime ticker woke {} times, longest gap {} us",
        busy.as_millis(),
        checks,
        busy.as_micros() / u64::from(checks.max(1)),
        wakes,
        gap
    );
    kept_time(checks, wakes, gap.into(), busy, "the realtime ticker waited behind the main executor")
}

/// Checks ed25519 signatures (what an update's verification does, several ms each on the
/// Cortex-M4) for [`BUSY`] without yielding (the key and the signature made first): how many (0
/// when a valid one was refused), and how long the checks took.
fn busy() -> (u32, Duration) {
    let keypair = salty::Keypair::from(&[0x42; 32]);
    let message = [0x5A_u8; 82];
    let signature = keypair.sign(&message);
    let start = Instant::now();
    let mut checks = 0u32;
    while start.elapsed() < BUSY {
        if keypair.public.verify(&message, &signature).is_err() {
            return (0, start.elapsed());
        }
        checks += 1;
    }
    (checks, start.elapsed())
}

/// The verdict on a ticker that woke `wakes` times, its longest gap `gap` µs, while another
/// executor computed for `busy` (`checks` signatures): within 2 ms on the STM32 (within the
/// 8350 ring's 6.4 ms slack); under QEMU, whose clock is the wall clock of a shared PC, within
/// a quarter of the busy time (on one executor with the computing it would be all of it).
fn kept_time(checks: u32, wakes: u32, gap: u64, busy: Duration, behind: &'static str) -> Result<Verdict, &'static str> {
    let most = if cfg!(feature = "board-qemu") { busy.as_micros() / 4 } else { 2_000.min(u64::from(RING_SLACK_US)) };
    if checks == 0 {
        Err("a valid ed25519 signature was refused")
    } else if wakes == 0 || gap > most {
        Err(behind)
    } else {
        Ok(Verdict::Passed)
    }
}

/// Asks the background executor's task to compute ([`busy`]), and its answer.
static BACKGROUND_GO: Signal<CriticalSectionRawMutex, ()> = Signal::new();
static BACKGROUND_DONE: Signal<CriticalSectionRawMutex, (u32, Duration)> = Signal::new();

/// On the board's background executor (thread mode, below the main one: where MQTT's service
/// runs): [`busy`] at each [`BACKGROUND_GO`], as MQTT computes a TLS handshake's P-256.
#[embassy_executor::task]
pub async fn background_busy() -> ! {
    loop {
        BACKGROUND_GO.wait().await;
        BACKGROUND_DONE.signal(busy());
    }
}

/// The main executor preempts the background one: its 1 ms ticker keeps time ([`kept_time`]).
async fn background() -> Result<Verdict, &'static str> {
    use embassy_futures::select::{select, Either};
    BACKGROUND_DONE.reset();
    BACKGROUND_GO.signal(());
    let start = Instant::now();
    let mut ticker = embassy_time::Ticker::every(REALTIME_TICK);
    let (mut last, mut gap, mut wakes) = (start, 0u64, 0u32);
    let (checks, busy) = loop {
        match select(ticker.next(), BACKGROUND_DONE.wait()).await {
            Either::First(()) => {
                let now = Instant::now();
                (gap, last, wakes) = (gap.max((now - last).as_micros()), now, wakes + 1);
                if now - start > BUSY * 20 {
                    return Err("the background executor's task did not finish: it did not run");
                }
            }
            Either::Second(done) => break done,
        }
    };
    say!(
        "on-target: the background executor busy {} ms ({} ed25519 checks); the main executor's ticker woke {} times, longest gap {} us",
        busy.as_millis(),
        checks,
        wakes,
        gap
    );
    kept_time(checks, wakes, gap, busy, "the main executor's ticker waited behind the background executor")
}

/// Waits up to 5 s for the network stack's link.
async fn link_up(stack: embassy_net::Stack<'static>) -> Result<(), &'static str> {
    let deadline = Instant::now() + Duration::from_secs(5);
    while !stack.is_link_up() {
        if Instant::now() > deadline {
            return Err("no link within 5 s");
        }
        Timer::after_millis(100).await;
    }
    Ok(())
}

/// The painted stack's high-water mark (boards/stack.rs, issue #39) after every check above:
/// said, and held to the stack this image has, with 1 KiB to spare. docs/design.md ("Memory
/// plan") compares it with the 32 KiB the plan keeps.
fn stack_mark() -> Result<Verdict, &'static str> {
    #[cfg(feature = "board-qemu")]
    let (used, size) = remodaq_board_qemu::stack::stack_high_water();
    #[cfg(not(feature = "board-qemu"))]
    let (used, size) = remodaq_board_stm32::stack::stack_high_water();
    say!("on-target: stack high-water mark {} of {} bytes", used, size);
    passed(if used + 1024 <= size { Ok(()) } else { Err("less than 1 KiB of the stack left at its high-water mark") })
}

#[cfg(feature = "board-qemu")]
async fn board_checks(report: &mut Report, spawner: Spawner, board: B, (): ()) {
    let (net, _) = board.start_network(spawner, remodaq_shared::net::NetConfig::FACTORY);
    report.check("LAN9118: the driver brings the link up", passed(link_up(net.stack).await));
}

#[cfg(not(feature = "board-qemu"))]
async fn board_checks(report: &mut Report, spawner: Spawner, board: B, io: remodaq_board_stm32::Io) {
    let (net, _) = board.start_network(spawner, remodaq_shared::net::NetConfig::FACTORY);
    report.check("PHY: link up (Ethernet cable to a switch)", passed(link_up(net.stack).await));
    // The board was taken apart by `start_network`: the PA12 hold must have outlived it.
    let held = if remodaq_board_stm32::pa12_held() {
        Ok(())
    } else {
        Err("PA12 released: bank-2 reads panic on silicon before rev 3")
    };
    report.check("PA12 held (output, pull-down, low) after the network started (errata ES0206 2.2.11)", passed(held));
    let (spi, ntc) = io.analog.start();
    report.check("AD7124-8: reset, id and set-up over SPI1", passed(ad7124(spi, ntc).await));
    let (train, latency) = loopback(io.digital).await;
    report.check("capture and outputs: DO0 -> DI0 jumper, 1000 pulses counted", passed(train));
    report.check("DO0 write to pin within 1 ms: 100 writes, DI0 follows through the jumper", passed(latency));
}

#[cfg(not(feature = "board-qemu"))]
async fn ad7124(
    spi: remodaq_board_stm32::analog::AdcSpi,
    ntc: remodaq_board_stm32::analog::NtcInput,
) -> Result<(), &'static str> {
    use remodaq_8318::acquisition::AnalogFrontEnd;
    let mut fe = remodaq_8318::ad7124::Ad7124FrontEnd::new(spi, ntc);
    fe.measure(0, 100.0, true).await.map(|_| ()).map_err(|_| "the AD7124-8 does not answer as expected")
}

/// DO0 plays a train of exactly 1000 pulses (0.5 ms high, 0.5 ms low) through the timer-DMA
/// output pattern; the jumper brings it to DI0, captured by timer-DMA at 50 kHz and counted by
/// the DI engine: 1000 rising edges, no samples lost. Then (issue #23) DO0 in normal mode is
/// written 100 times, on and off, 15 ms apart: each write must reach the pattern within 1 ms by
/// the module's own measure (the output task's delay plus the ticks from the DMA's position,
/// read from NDTR, to the first rewritten: 40326), and DI0 must follow through the jumper.
#[cfg(not(feature = "board-qemu"))]
async fn loopback(
    digital: remodaq_board_stm32::resources::DigitalPeripherals,
) -> (Result<(), &'static str>, Result<(), &'static str>) {
    use core::cell::RefCell;

    use embassy_futures::select::select;
    use remodaq_8350::di::{DiMode, SAMPLE_RATE_HZ};
    use remodaq_8350::io::{self, Io, IoCell};
    use remodaq_8350::pulse::{DoMode, PulseConfig};
    use remodaq_shared::diagnostics::{status, DIAGNOSTICS};
    use remodaq_shared::settings::Schema;

    let mut settings = remodaq_8350::settings::Settings::defaults();
    settings.di_modes[0] = DiMode::Counter;
    settings.do_modes[0] = DoMode::Pulse;
    settings.pulses[0] = PulseConfig { low: 5, high: 5, count: 1000 };
    static CELL: static_cell::StaticCell<IoCell<embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex>> =
        static_cell::StaticCell::new();
    let cell = CELL.init(IoCell::new(RefCell::new(Io::new(SAMPLE_RATE_HZ, &settings))));
    io::with(cell, |s| s.di.set_run(0, true));
    let (capture, pattern) = digital.start();
    let run = io::run(capture, pattern, cell, || {});
    let mut counted = 0;
    let mut latency = Ok(());
    let test = async {
        Timer::after_millis(100).await;
        io::with(cell, |s| {
            s.pulse.set_do(0, true);
            s.outputs_commanded();
        });
        // 1000 pulses of 1 ms, and the output ring's lead.
        Timer::after_millis(1300).await;
        counted = io::with(cell, |s| s.di.counter_value(0));
        io::with(cell, |s| {
            s.pulse.set_mode(0, DoMode::Normal);
            s.di.set_mode(0, DiMode::Normal);
            s.outputs_commanded();
        });
        Timer::after_millis(20).await;
        let mut worst = 0;
        for i in 0..100 {
            let on = i % 2 == 0;
            io::with(cell, |s| {
                s.pulse.set_do(0, on);
                s.outputs_commanded();
            });
            Timer::after_millis(15).await;
            worst = worst.max(DIAGNOSTICS.read(remodaq_shared::diagnostics::Diag::OutputLatency, 0));
            if io::with(cell, |s| s.di.state() & 1 == 1) != on {
                latency = Err("DI0 did not follow DO0 within 15 ms (is the jumper in place?)");
            }
        }
        say!("on-target: DO0 write to the pattern, worst of 100 writes {} µs", worst);
        if latency.is_ok() && worst > 1000 {
            latency = Err("a DO0 write took more than 1 ms to reach the pattern");
        }
    };
    select(run, test).await;
    say!("on-target: DI0 counted {} rising edges", counted);
    let train = if DIAGNOSTICS.status() & status::FRONT_END_FAULT != 0 {
        Err("input samples were lost")
    } else if counted != 1000 {
        Err("DI0 did not count the 1000 pulses of DO0 (is the jumper in place?)")
    } else {
        Ok(())
    };
    (train, latency)
}

fn exit(ok: bool) -> ! {
    #[cfg(feature = "board-qemu")]
    cortex_m_semihosting::debug::exit(if ok {
        cortex_m_semihosting::debug::EXIT_SUCCESS
    } else {
        cortex_m_semihosting::debug::EXIT_FAILURE
    });
    #[cfg(not(feature = "board-qemu"))]
    {
        // probe-rs ends the run at a breakpoint; a failure is a panic (panic-probe: exit 1).
        if !ok {
            defmt::panic!("on-target checks failed");
        }
        cortex_m::asm::bkpt();
    }
    loop {
        cortex_m::asm::wfi();
    }
}
