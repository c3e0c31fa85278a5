//! A new image's trial and confirmation at the start of the update task: [`start`], [`confirm`]
//! and its [`Confirmation`], the [`self_test_passed`] it waits for, and the test images' forged
//! swap (feature `test-unsigned-swap`).

use embassy_time::Duration;
use embedded_storage_async::nor_flash::NorFlash;

#[cfg(feature = "test-unsigned-swap")]
use remodaq_protocol::update::{Header, Status, HEADER_LEN};
use remodaq_shared::board::{Network, Shared};
use remodaq_shared::module::{CommonSettings, SettingsAccess, Store};

use crate::boot::BootUpdater;
#[cfg(feature = "test-unsigned-swap")]
use crate::boot::MANIFEST_LEN;
use crate::session::UpdateService;
#[cfg(feature = "test-unsigned-swap")]
use crate::target::UpdateTarget;

/// How long a new image may take to pass its self-test before the module restarts (and the
/// bootloader reverts to the previous image): 20 s; 10 s on the QEMU board's test images
/// (feature `short-trial`: their self-test passes within about a second, and the end-to-end
/// checks wait out a trial five times, docs/update.md).
pub const TRIAL: Duration = Duration::from_secs(if cfg!(feature = "short-trial") { 10 } else { 20 });

/// The self-test a new image must pass to confirm itself: the network up, the inputs valid
/// (the front end answers: first acquisition done, no front-end fault), and the settings store
/// working (no failed commit).
pub fn self_test_passed(network_up: bool) -> bool {
    use remodaq_shared::diagnostics::{status, DIAGNOSTICS};
    let s = DIAGNOSTICS.status();
    network_up && s & (status::INPUTS_PENDING | status::FRONT_END_FAULT | status::STORE_FAULT) == 0
}

/// The start of the update task of a board with a bootloader: confirms a new (or reverted-to)
/// image once its self-test passes, or restarts it (the bootloader then reverts) when it has not
/// passed after [`TRIAL`]. Returns the update partition's writer (over `aligned`, the state
/// partition's write buffer) and the service, which then serve update sessions forever on the
/// board's network ([`embassy::serve`](crate::embassy::serve) on the embassy-net boards).
#[allow(clippy::too_many_arguments)]
pub async fn start<'d, N, A, F, DFU, STATE>(
    net: &'static N,
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    model: u16,
    mac: [u8; 6],
    dfu: DFU,
    state: STATE,
    aligned: &'d mut [u8; 32],
) -> (BootUpdater<'d, DFU, STATE>, UpdateService)
where
    N: Network,
    A: SettingsAccess,
    F: NorFlash,
    DFU: NorFlash,
    STATE: NorFlash,
{
    // The state buffer is STATE's write size: at most 32 bytes on the targets.
    const { assert!(STATE::WRITE_SIZE <= 32 && STATE::READ_SIZE <= STATE::WRITE_SIZE) };
    // The update partition is the running one plus a page for the swap.
    let capacity = (dfu.capacity() - DFU::ERASE_SIZE) as u32;
    let mut target = BootUpdater::new(
        dfu,
        state,
        &mut aligned[..STATE::WRITE_SIZE],
        remodaq_shared::identity::update_key(),
        capacity,
    );
    let self_test = || self_test_passed(net.is_up()) && !cfg!(feature = "never-confirm");
    if confirm(&mut target, map, store, self_test, TRIAL).await == Confirmation::NotPassed {
        remodaq_shared::error!("update: self-test not passed in time: restarting (the bootloader reverts)");
        net.restart().await;
    }
    #[cfg(feature = "test-unsigned-swap")]
    forge_unsigned_swap(net, &mut target).await;
    (target, UpdateService::new(model, mac, capacity))
}

/// Test images only (feature `test-unsigned-swap`, the QEMU check of the bootloader): once
/// confirmed, the image writes junk into the update partition with a manifest whose signature
/// is not the key's, marks it for a swap and restarts, as code that took over the module might.
/// The bootloader must refuse the swap: this same image starts again, finds its junk there and
/// goes on serving.
#[cfg(feature = "test-unsigned-swap")]
#[allow(clippy::single_match, reason = "the `Err` arm logs, but is empty in a build without a log backend")]
async fn forge_unsigned_swap<N, DFU, STATE>(net: &N, target: &mut BootUpdater<'_, DFU, STATE>)
where
    N: Network,
    DFU: NorFlash,
    STATE: NorFlash,
{
    const MARK: &[u8; 8] = b"RDQ-JUNK";
    let mut first = [0u8; 8];
    if target.read_dfu(0, &mut first).await.is_ok() && first == *MARK {
        remodaq_shared::warn!("update: the forged swap was refused: still running this image");
        return;
    }
    let mut junk = [0xA5u8; 4096];
    junk[..8].copy_from_slice(MARK);
    // An identity the bootloader's model and counter check lets through (this model, the
    // highest counter), so that the signature alone refuses the swap.
    let at = remodaq_protocol::update::IDENTITY_AT as usize;
    let identity = remodaq_protocol::update::Identity { model: 0x8350, counter: u32::MAX };
    junk[at..at + remodaq_protocol::update::IDENTITY_LEN].copy_from_slice(&identity.encode());
    let digest = salty::Sha512::new().updated(&junk).finalize();
    let forged =
        Header { model: 0x8350, version: 0xFFFF, counter: u32::MAX, length: 4096, digest, signature: [0x42; 64] };
    let mut manifest = [0xFFu8; MANIFEST_LEN];
    manifest[..HEADER_LEN].copy_from_slice(&forged.encode());
    let manifest_at = target.manifest_at;
    let written = async {
        target.begin().await?;
        target.write(0, &junk).await?;
        target.write(manifest_at, &manifest).await?;
        target.state.mark_updated().await.map_err(|_| Status::StoreFailed)
    };
    match written.await {
        Ok(()) => {
            remodaq_shared::warn!("update: junk with a forged manifest marked for a swap: restarting");
            net.restart().await
        }
        Err(_) => remodaq_shared::error!("update: the forged swap could not be written"),
    }
}

/// What [`confirm`] found at the start, and did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Confirmation {
    /// The image was confirmed before: nothing to do.
    Confirmed,
    /// A new image passed its self-test within its trial and is confirmed now.
    Passed,
    /// The bootloader reverted to this (previous, once confirmed) image: marked booted without
    /// a trial. The bootloader does nothing more in this state, so a trial that failed would
    /// only restart this same image for ever.
    Reverted,
    /// A new image did not pass its self-test within its trial: the caller restarts the module
    /// and the bootloader reverts to the previous image.
    NotPassed,
    /// The bootloader's state cannot be read.
    Unreadable,
}

/// Confirms the running image after a swap once `self_test` passes, within `trial`; confirms an
/// image the bootloader reverted to at once; and keeps the security counters in the settings
/// (anti-rollback, docs/update.md).
pub async fn confirm<A, F, DFU, STATE>(
    target: &mut BootUpdater<'_, DFU, STATE>,
    map: &Shared<A>,
    store: &Store<F, A::Settings>,
    mut self_test: impl FnMut() -> bool,
    trial: Duration,
) -> Confirmation
where
    A: SettingsAccess,
    F: NorFlash,
    DFU: NorFlash,
    STATE: NorFlash,
{
    use embassy_boot::State;
    // The counters once the image in the state `reverted` (or not) is confirmed: a new image's
    // counter becomes the module's; after a revert, the pending one is dropped.
    let settle = |reverted: bool| {
        move |s: &mut A::Settings| {
            let mut c = s.update_counter();
            if !reverted {
                c.confirmed = c.confirmed.max(c.pending);
            }
            c.pending = 0;
            s.set_update_counter(c);
        }
    };
    match target.state().await {
        Ok(State::Swap) => remodaq_shared::info!("update: running a new image on trial"),
        Ok(State::Revert) => {
            remodaq_shared::warn!("update: the new image did not confirm itself; running the previous one");
            if target.mark_booted().await.is_err() {
                remodaq_shared::error!("update: the previous image could not be confirmed");
            }
            if remodaq_shared::module::commit_counters(map, store, settle(true)).await.is_err() {
                remodaq_shared::error!("update: the counters could not be stored");
            }
            return Confirmation::Reverted;
        }
        Ok(_) => return Confirmation::Confirmed,
        Err(_) => {
            remodaq_shared::error!("update: the bootloader's state cannot be read");
            return Confirmation::Unreadable;
        }
    }
    let deadline = embassy_time::Instant::now() + trial;
    loop {
        if self_test() {
            // Anti-rollback first (security review finding 11a): from now on, images below
            // this one's counter are refused. Committed before the image is confirmed, so that
            // a cut between the two leaves the counter raised (and the image unconfirmed: the
            // next start reverts, the older image runs), never an image confirmed under the
            // old counter. A counter that cannot be stored confirms nothing.
            if remodaq_shared::module::commit_counters(map, store, settle(false)).await.is_err() {
                remodaq_shared::error!("update: the security counter could not be stored; image not confirmed");
            } else if target.mark_booted().await.is_ok() {
                remodaq_shared::info!("update: self-test passed, image confirmed");
                return Confirmation::Passed;
            } else {
                // Tried again until the trial ends; then the restart reverts.
                remodaq_shared::error!("update: the image could not be confirmed");
            }
        }
        if embassy_time::Instant::now() > deadline {
            return Confirmation::NotPassed;
        }
        embassy_time::Timer::after_millis(100).await;
    }
}
