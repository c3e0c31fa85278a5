//! The firmware update service and the bootloader it feeds, over RAM flashes: a signed image
//! streamed into the update partition and marked; refusals (password, model, signature,
//! truncation) that change nothing; and embassy-boot's swap and revert with the power cut at
//! every write and erase: after each cut, the old or the new image boots, never a mix.
#[path = "../../../shared/tests/common/mod.rs"]
mod common;

use core::cell::Cell;

use common::{Live, Script, S};
use ed25519_dalek::{Signer, SigningKey};
use embassy_boot::{BootLoader, BootLoaderConfig, State};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::mutex::Mutex;
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use futures_executor::block_on;
use remodaq_protocol::auth::{client_proof, derive, server_signature, Credential};
use remodaq_protocol::update::{
    answer_message, auth_message, check_before_swap, BeforeSwap, Greeting, Identity, GREETING_LEN, HEADER_LEN,
    IDENTITY_AT, OPENING, SIGNED_LEN,
};
use remodaq_shared::ram_flash::{RamFlash, RamFlashError};
use remodaq_shared::settings::Counter;
use remodaq_shared::settings::Schema;
use remodaq_shared::settings::SettingsStore;
#[cfg(feature = "web")]
use remodaq_shared::upload::{WebDone, WebStep, WEB_CHUNK};
use remodaq_update::{BootUpdater, Header, Outcome, Status, UpdateService};
use sha2::{Digest, Sha512};

/// The swap's page: larger than the service's 1 KiB chunk, as the boards' 128 KiB sectors are.
const PAGE: usize = 4096;
/// The running image's partition: 4 pages.
type Active = RamFlash<{ 4 * PAGE }, PAGE>;
/// The update partition: one page more (the swap's scratch page).
type Dfu = RamFlash<{ 5 * PAGE }, PAGE>;
type StateFlash = RamFlash<PAGE, PAGE>;

const MODEL: u16 = 0x8350;

/// The key pair of these tests (the firmware takes its public key from a file at build time).
fn key() -> SigningKey {
    SigningKey::from_bytes(&[0x5A; 32])
}

/// A firmware of `len` bytes, with the identity of this module's model and security counter 0
/// where every image has it (the bootloader reads it: `check_before_swap`).
fn image(seed: u8, len: usize) -> Vec<u8> {
    image_of(seed, len, Identity { model: MODEL, counter: 0 })
}

fn image_of(seed: u8, len: usize, identity: Identity) -> Vec<u8> {
    let mut bytes: Vec<u8> = (0..len).map(|i| (i as u8).wrapping_mul(31).wrapping_add(seed)).collect();
    bytes[IDENTITY_AT as usize..][..16].copy_from_slice(&identity.encode());
    bytes
}

/// An image file: header (signed with `key`) and firmware, security counter 0.
fn signed(firmware: &[u8], version: u16, key: &SigningKey) -> Vec<u8> {
    signed_as(firmware, MODEL, version, 0, key)
}

/// An image file as `remodaq sign` writes it (docs/update.md): the header's first SIGNED_LEN
/// bytes signed.
fn signed_as(firmware: &[u8], model: u16, version: u16, counter: u32, key: &SigningKey) -> Vec<u8> {
    let digest = Sha512::digest(firmware).into();
    let mut header = Header { model, version, counter, length: firmware.len() as u32, digest, signature: [0; 64] };
    header.signature = key.sign(&header.encode()[..SIGNED_LEN]).to_bytes();
    [&header.encode()[..], firmware].concat()
}

/// The module's configuration password in these tests (updates are refused while the factory
/// one is in force).
const PASSWORD: &str = "plant password";

/// What the PC sends in a session: the password it proves, the image file (cut after `cut`
/// bytes).
type Plan = (String, Vec<u8>);

fn session_bytes(password: &str, file: &[u8], cut: Option<usize>) -> Plan {
    (password.to_string(), file[..cut.unwrap_or(file.len()).min(file.len())].to_vec())
}

/// The PC's side of a session over a [`Script`]: its nonce first; once the module's greeting
/// is in, the proof and the (cut) image file, in segments of 300 bytes as a TCP stream may
/// deliver them. Afterwards [`Pc::statuses`] checks the module's signatures.
struct Pc {
    io: Script,
    plan: Plan,
    proved: Option<([u8; 32], [u8; HEADER_LEN], Greeting)>,
    /// Everything the PC sent, as a recorder on the LAN sees it.
    sent: Vec<u8>,
    /// A byte of the header a man in the middle changes after the PC proved it.
    alter: Option<usize>,
}

const CNONCE: [u8; 16] = [0xC0; 16];

impl Pc {
    fn new(plan: Plan) -> Self {
        let mut io = Script::new(&[]);
        let opening = [&OPENING[..], &CNONCE[..]].concat();
        io.incoming.push_back(opening.clone());
        Self { io, plan, proved: None, sent: opening, alter: None }
    }

    /// The module's answers: one status each, its signature checked where it must have one.
    fn statuses(&self) -> Vec<u8> {
        let out = &self.io.outgoing;
        let Some((server_key, header, g)) = &self.proved else { return out.clone() };
        let message = auth_message(&g.mac, &CNONCE, &g.snonce, header);
        let mut rest = &out[GREETING_LEN..];
        let mut statuses = Vec::new();
        for step in 0..2u8 {
            let Some((&status, tail)) = rest.split_first() else { break };
            statuses.push(status);
            rest = tail;
            if Status::from_code(status).is_some_and(Status::after_proof) {
                let (signature, tail) = rest.split_at(32);
                let expected = server_signature(server_key, &answer_message(&message, &[step], &[status]));
                assert_eq!(signature, expected, "the module's signature on answer {step}");
                rest = tail;
            }
        }
        assert!(rest.is_empty(), "nothing after the answers");
        statuses
    }
}

impl embedded_io_async::ErrorType for Pc {
    type Error = core::convert::Infallible;
}

impl embedded_io_async::Read for Pc {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        self.io.read(buf).await
    }
}

impl embedded_io_async::Write for Pc {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let n = self.io.write(buf).await?;
        if self.proved.is_none() && self.io.outgoing.len() >= GREETING_LEN {
            let g = Greeting::decode(self.io.outgoing[..GREETING_LEN].try_into().unwrap());
            let (password, file) = &self.plan;
            let (client_key, credential) = derive(password.as_bytes(), &g.salt, g.iterations);
            let mut header = [0u8; HEADER_LEN];
            let n = file.len().min(HEADER_LEN);
            header[..n].copy_from_slice(&file[..n]);
            let proof = client_proof(&client_key, &auth_message(&g.mac, &CNONCE, &g.snonce, &header));
            let mut bytes = [&proof[..], file].concat();
            if let Some(at) = self.alter {
                bytes[32 + at] ^= 1;
            }
            self.sent.extend_from_slice(&bytes);
            self.io.incoming.extend(bytes.chunks(300).map(<[u8]>::to_vec));
            self.proved = Some((credential.server_key, header, g));
        }
        Ok(n)
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// The test password's credential.
fn credential() -> Credential {
    derive(PASSWORD.as_bytes(), &[0x77; 16], 4096).1
}

/// Runs sessions, one after the other, against the update and state partitions through one
/// service and one updater (as the module does); the module's answers and the outcome of each.
fn sessions(dfu: &mut Dfu, state: &mut StateFlash, each: Vec<Plan>) -> Vec<(Vec<u8>, Outcome)> {
    let settings = S { password: credential(), ..S::defaults() };
    sessions_with(settings, dfu, state, each).0
}

type SettingsFlash = RamFlash<4096, 1024>;

/// A settings store on a blank flash, holding `settings` when given (the defaults otherwise).
fn store_with(settings: Option<S>) -> Mutex<CriticalSectionRawMutex, SettingsStore<SettingsFlash, S>> {
    let mut store = block_on(SettingsStore::open(
        SettingsFlash::new(),
        const { SettingsStore::<SettingsFlash, S>::config(0..4096) },
    ));
    if let Some(settings) = settings {
        block_on(store.commit(settings)).unwrap();
    }
    Mutex::new(store)
}

/// Sessions against a module with `settings`; the answers and outcomes, and the settings after.
fn sessions_with(settings: S, dfu: &mut Dfu, state: &mut StateFlash, each: Vec<Plan>) -> (Vec<(Vec<u8>, Outcome)>, S) {
    sessions_as(MODEL, settings, dfu, state, each)
}

/// [`sessions_with`] by an update service that takes itself for `model`.
fn sessions_as(
    model: u16,
    settings: S,
    dfu: &mut Dfu,
    state: &mut StateFlash,
    each: Vec<Plan>,
) -> (Vec<(Vec<u8>, Outcome)>, S) {
    let store = store_with(Some(settings));
    let map = Mutex::<NoopRawMutex, _>::new(Live(settings));
    let mut aligned = [0u8; 4];
    let mut target = updater(dfu, state, &mut aligned);
    let mut service = UpdateService::new(model, [2, 0, 0, 0, 0, 1], 4 * PAGE as u32);
    let results = each
        .into_iter()
        .enumerate()
        .map(|(i, plan)| {
            let mut pc = Pc::new(plan);
            let _ = i;
            // One session at a time in this process, each at a later time than the last: a
            // session run late with an earlier time would find the budget spent by a later one.
            let (_turn, now) = session_time();
            let outcome = block_on(service.session(&mut pc, [127, 0, 0, 1], now, &map, &store, &mut target));
            (pc.statuses(), outcome)
        })
        .collect();
    let after = block_on(map.lock()).0;
    (results, after)
}

/// The time of a session, and this process's turn to run one: each two minutes after the last
/// one (the tests run in parallel threads and share the module-wide guessing budget, a static:
/// a wrong proof in one test must not leave the budget spent for another). The turn is held
/// through the session, so that sessions run in the order of their times: one run late with an
/// earlier time would find the budget of a later one.
fn session_time() -> (std::sync::MutexGuard<'static, ()>, u64) {
    static TURN: std::sync::Mutex<()> = std::sync::Mutex::new(());
    static CLOCK: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    (turn, CLOCK.fetch_add(120_000, std::sync::atomic::Ordering::SeqCst))
}

/// Where the module writes the manifest for the bootloader: the start of the update
/// partition's last page.
const MANIFEST_AT: u32 = 4 * PAGE as u32;

/// The update target over `dfu` and `state`, for this test key's images.
fn updater<'d, D, St>(dfu: D, state: St, aligned: &'d mut [u8]) -> BootUpdater<'d, D, St>
where
    D: embedded_storage_async::nor_flash::NorFlash,
    St: embedded_storage_async::nor_flash::NorFlash,
{
    BootUpdater::new(dfu, state, aligned, key().verifying_key().to_bytes(), MANIFEST_AT)
}

/// One session.
fn session(dfu: &mut Dfu, state: &mut StateFlash, plan: Plan) -> (Vec<u8>, Outcome) {
    sessions(dfu, state, vec![plan]).remove(0)
}

/// A flash whose power is cut after a budget of erases and word writes shared with the other
/// partitions (one power supply).
struct Powered<'a, F> {
    flash: &'a mut F,
    budget: &'a Cell<Option<usize>>,
}

impl<F> Powered<'_, F> {
    fn spend(&self, ops: usize) -> Result<(), RamFlashError> {
        match self.budget.get() {
            Some(left) if left < ops => {
                self.budget.set(Some(0));
                Err(RamFlashError::PowerCut)
            }
            Some(left) => {
                self.budget.set(Some(left - ops));
                Ok(())
            }
            None => Ok(()),
        }
    }
}

impl<F: ErrorType<Error = RamFlashError>> ErrorType for Powered<'_, F> {
    type Error = RamFlashError;
}

impl<F: ReadNorFlash + ErrorType<Error = RamFlashError>> ReadNorFlash for Powered<'_, F> {
    const READ_SIZE: usize = F::READ_SIZE;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.flash.read(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl<F: NorFlash + ErrorType<Error = RamFlashError>> NorFlash for Powered<'_, F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        // Page by page, so a cut can fall between two pages of one erase.
        for page in (from..to).step_by(F::ERASE_SIZE) {
            self.spend(1)?;
            self.flash.erase(page, page + F::ERASE_SIZE as u32)?;
        }
        Ok(())
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        for (i, word) in bytes.chunks(4).enumerate() {
            self.spend(1)?;
            self.flash.write(offset + 4 * i as u32, word)?;
        }
        Ok(())
    }
}

/// The three partitions of a module.
struct Module {
    active: Active,
    dfu: Dfu,
    state: StateFlash,
}

impl Module {
    fn copy(&self) -> Self {
        Self {
            active: RamFlash::from_image(self.active.image()),
            dfu: RamFlash::from_image(self.dfu.image()),
            state: RamFlash::from_image(self.state.image()),
        }
    }

    /// The bootloader at a start, with the power cut after `budget` operations.
    fn boot(&mut self, budget: Option<usize>) -> Result<State, embassy_boot::BootError> {
        let budget = Cell::new(budget);
        let config = BootLoaderConfig {
            active: Powered { flash: &mut self.active, budget: &budget },
            dfu: Powered { flash: &mut self.dfu, budget: &budget },
            state: Powered { flash: &mut self.state, budget: &budget },
        };
        let mut aligned = [0u8; 256];
        BootLoader::new(config).prepare_boot(&mut aligned)
    }

    /// Which image is in the running partition.
    fn running(&self, old: &[u8], new: &[u8]) -> &'static str {
        let active = &self.active.image()[..];
        if active.starts_with(new) {
            "new"
        } else if active.starts_with(old) {
            "old"
        } else {
            "neither"
        }
    }

    /// The new image confirms itself after its self-test.
    fn confirm(&mut self) {
        let mut aligned = [0u8; 4];
        let mut state = embassy_boot::BlockingFirmwareState::new(&mut self.state, &mut aligned);
        state.mark_booted().expect("mark booted");
    }
}

fn module_with(old: &[u8]) -> Module {
    Module { active: RamFlash::from_image(old), dfu: RamFlash::new(), state: RamFlash::new() }
}

#[test]
fn a_signed_image_is_streamed_verified_and_marked() {
    let (old, new) = (image(1, 3000), image(2, 3001));
    let mut m = module_with(&old);
    let file = signed(&new, 0xA101, &key());
    let (answers, outcome) = session(&mut m.dfu, &mut m.state, session_bytes(PASSWORD, &file, None));
    assert_eq!(answers, [Status::Ok as u8, Status::Ok as u8]);
    assert_eq!(outcome, Outcome::Updated { version: 0xA101 });
    assert_eq!(&m.dfu.image()[..new.len()], &new[..], "the firmware is in the update partition");
    assert_eq!(m.boot(None), Ok(State::Swap), "the bootloader swaps it in");
    assert_eq!(m.running(&old, &new), "new");
    m.confirm();
    assert_eq!(m.boot(None), Ok(State::Boot), "confirmed: it stays");
    assert_eq!(m.running(&old, &new), "new");
}

/// A recorded session sent again (a new session: the module's new nonce makes the recorded
/// proof worthless), and a session whose header a man in the middle changed (the proof covers
/// it): each refused with status 1 before anything is written.
#[test]
fn a_replayed_or_altered_session_changes_nothing() {
    let (old, new) = (image(1, 3000), image(2, 3001));
    let file = signed(&new, 0xA101, &key());
    let mut m = module_with(&old);
    let settings = S { password: credential(), ..S::defaults() };
    // The recording: a good session.
    let mut dfu: Dfu = RamFlash::from_image(m.dfu.image());
    let mut state: StateFlash = RamFlash::from_image(m.state.image());
    let mut recorded = Pc::new(session_bytes(PASSWORD, &file, None));
    let store = store_with(None);
    let map = Mutex::<NoopRawMutex, _>::new(Live(settings));
    {
        let mut aligned = [0u8; 4];
        let mut target = updater(&mut dfu, &mut state, &mut aligned);
        let mut service = UpdateService::new(MODEL, [2, 0, 0, 0, 0, 1], 4 * PAGE as u32);
        let (turn, now) = session_time();
        let outcome = block_on(service.session(&mut recorded, [127, 0, 0, 1], now, &map, &store, &mut target));
        drop(turn);
        assert_eq!((recorded.statuses(), outcome), (vec![0, 0], Outcome::Updated { version: 0xA101 }));
        // The replay: the recorded bytes, to the module as it was before.
        let mut aligned = [0u8; 4];
        let mut target = updater(&mut m.dfu, &mut m.state, &mut aligned);
        let mut replay = Script::new(&[]);
        replay.incoming = recorded.sent.chunks(300).map(<[u8]>::to_vec).collect();
        let (turn, now) = session_time();
        let outcome = block_on(service.session(&mut replay, [127, 0, 0, 66], now, &map, &store, &mut target));
        drop(turn);
        assert_eq!(outcome, Outcome::NotUpdated, "the replay");
        assert_eq!(
            replay.outgoing.get(GREETING_LEN..),
            Some(&[Status::WrongPassword as u8][..]),
            "the replay: status 1"
        );
    }
    assert_eq!((m.boot(None), m.running(&old, &new)), (Ok(State::Boot), "old"), "the replay changed nothing");
    // Altered: the counter byte of the header changed after the PC proved it.
    let mut altered = Pc::new(session_bytes(PASSWORD, &file, None));
    altered.alter = Some(13);
    let mut m = module_with(&old);
    let mut aligned = [0u8; 4];
    let mut target = updater(&mut m.dfu, &mut m.state, &mut aligned);
    let mut service = UpdateService::new(MODEL, [2, 0, 0, 0, 0, 1], 4 * PAGE as u32);
    let (turn, now) = session_time();
    let outcome = block_on(service.session(&mut altered, [127, 0, 0, 1], now, &map, &store, &mut target));
    drop(turn);
    assert_eq!((altered.statuses(), outcome), (vec![Status::WrongPassword as u8], Outcome::NotUpdated), "altered");
    assert_eq!((m.boot(None), m.running(&old, &new)), (Ok(State::Boot), "old"), "the altered session changed nothing");
}

#[test]
fn an_older_counter_or_the_other_models_image_is_refused_and_the_counter_moves_on_confirmation() {
    let (old, new) = (image(1, 3000), image(2, 3001));
    // The module confirmed an image with counter 5.
    let settings = S { password: credential(), update: Counter { confirmed: 5, pending: 0 }, ..S::defaults() };
    let cases = [
        ("counter 4: an older release", signed_as(&new, MODEL, 0xA101, 4, &key()), vec![Status::Downgrade as u8]),
        ("the 8318's image", signed_as(&new, 0x8318, 0xA101, 9, &key()), vec![Status::Invalid as u8]),
    ];
    for (what, file, want) in cases {
        let mut m = module_with(&old);
        let (mut results, after) =
            sessions_with(settings, &mut m.dfu, &mut m.state, vec![session_bytes(PASSWORD, &file, None)]);
        assert_eq!(results.remove(0), (want, Outcome::NotUpdated), "{what}");
        assert_eq!(after.update, settings.update, "{what}: the counters unchanged");
        assert_eq!((m.boot(None), m.running(&old, &new)), (Ok(State::Boot), "old"), "{what}");
    }
    // Counter 6: taken, and pending until the image confirms itself.
    let mut m = module_with(&old);
    let file = signed_as(&new, MODEL, 0xA101, 6, &key());
    let (mut results, after) =
        sessions_with(settings, &mut m.dfu, &mut m.state, vec![session_bytes(PASSWORD, &file, None)]);
    assert_eq!(results.remove(0), (vec![0, 0], Outcome::Updated { version: 0xA101 }));
    assert_eq!(after.update, Counter { confirmed: 5, pending: 6 });
}

#[test]
fn the_bootloader_checks_the_manifest_before_the_swap() {
    let (old, new) = (image(1, 3000), image(2, 3001));
    let public = key().verifying_key().to_bytes();
    let mut m = module_with(&old);
    let check = |m: &mut Module| check_before_swap(&mut m.active, &mut m.dfu, &mut m.state, MANIFEST_AT, &public);
    assert_eq!(check(&mut m), BeforeSwap::Nothing, "no swap requested");
    let file = signed(&new, 0xA101, &key());
    let (answers, _) = session(&mut m.dfu, &mut m.state, session_bytes(PASSWORD, &file, None));
    assert_eq!(answers, [0, 0]);
    assert_eq!(&m.dfu.image()[MANIFEST_AT as usize..][..HEADER_LEN], &file[..HEADER_LEN], "the manifest");
    assert_eq!(check(&mut m.copy()), BeforeSwap::Verified);
    // Something else wrote the update partition after the module verified it: a firmware byte,
    // the manifest's counter, or no manifest at all.
    for (what, at) in [("firmware", 100), ("manifest", MANIFEST_AT as usize + 13)] {
        let mut image = m.dfu.image().to_vec();
        image[at] ^= 1;
        let mut tampered = m.copy();
        tampered.dfu = RamFlash::from_image(&image);
        assert_eq!(check(&mut tampered), BeforeSwap::Refuse, "{what}");
    }
    let mut image = m.dfu.image().to_vec();
    image[MANIFEST_AT as usize..].fill(0xFF);
    let mut erased = m.copy();
    erased.dfu = RamFlash::from_image(&image);
    assert_eq!(check(&mut erased), BeforeSwap::Refuse, "no manifest");
    // The power cut at every step of the swap, then the check at the next start: before the
    // swap has recorded progress, ACTIVE is untouched and the check may cancel (the old image
    // runs); once it has, the check stands aside and the swap finishes (the new image runs).
    // Never a mix.
    let mut seen = std::collections::BTreeMap::new();
    for cut in 0.. {
        let mut started = m.copy();
        if started.boot(Some(cut)).is_ok() {
            break;
        }
        let verdict = check(&mut started);
        *seen.entry(format!("{verdict:?}")).or_insert(0) += 1;
        match verdict {
            BeforeSwap::Nothing => {
                started.boot(None).unwrap();
                assert_eq!(started.running(&old, &new), "new", "cut {cut}: the swap finished");
            }
            _ => {
                assert_eq!(started.running(&old, &new), "old", "cut {cut}: ACTIVE untouched");
                if verdict == BeforeSwap::Verified {
                    started.boot(None).unwrap();
                    assert_eq!(started.running(&old, &new), "new", "cut {cut}");
                }
            }
        }
    }
    eprintln!("the check after a cut in the swap: {seen:?}");
    assert!(seen.contains_key("Nothing"), "{seen:?}");
}

/// The bootloaders check the model and the security counter themselves (security review
/// finding 11c), against the identity compiled into the running image, whatever the
/// application checked before it marked the update: here the update service of a module that
/// takes itself for the image's model with no counter confirmed marks each (as a compromised or
/// mistaken application could). Against 4cfaadc, whose check knew neither, each was `Verified`.
#[test]
fn the_bootloader_refuses_another_models_or_an_older_image_whoever_marked_it() {
    let public = key().verifying_key().to_bytes();
    let old = image_of(1, 3000, Identity { model: MODEL, counter: 5 });
    let id = |model, counter| Identity { model, counter };
    let cases = [
        ("the 8318's image, signed for the 8318", id(0x8318, 5), id(0x8318, 5), BeforeSwap::Refuse),
        ("an older release (counter 4)", id(MODEL, 4), id(MODEL, 4), BeforeSwap::Refuse),
        ("a header naming another counter than the image's", id(MODEL, 4), id(MODEL, 6), BeforeSwap::Refuse),
        ("a header naming another model than the image's", id(0x8318, 5), id(MODEL, 5), BeforeSwap::Refuse),
        ("the running release again (counter 5)", id(MODEL, 5), id(MODEL, 5), BeforeSwap::Verified),
        ("a newer release (counter 6)", id(MODEL, 6), id(MODEL, 6), BeforeSwap::Verified),
    ];
    for (what, built, named, want) in cases {
        let new = image_of(2, 3001, built);
        let mut m = module_with(&old);
        let file = signed_as(&new, named.model, 0xA101, named.counter, &key());
        let settings = S { password: credential(), ..S::defaults() };
        let (mut results, _) =
            sessions_as(named.model, settings, &mut m.dfu, &mut m.state, vec![session_bytes(PASSWORD, &file, None)]);
        assert_eq!(results.remove(0), (vec![0, 0], Outcome::Updated { version: 0xA101 }), "{what}: marked");
        assert_eq!(check_before_swap(&mut m.active, &mut m.dfu, &mut m.state, MANIFEST_AT, &public), want, "{what}");
    }
    // A running image without an identity (or one that cannot be read) takes no update.
    let mut m = module_with(&image(1, 3000)[..IDENTITY_AT as usize]);
    let file = signed(&image(2, 3001), 0xA101, &key());
    let results = sessions(&mut m.dfu, &mut m.state, vec![session_bytes(PASSWORD, &file, None)]);
    assert_eq!(results[0].0, [0, 0], "marked");
    assert_eq!(
        check_before_swap(&mut m.active, &mut m.dfu, &mut m.state, MANIFEST_AT, &public),
        BeforeSwap::Refuse,
        "no identity in the running image"
    );
}

/// A state partition whose reads fail from `from` on (a flash fault), for the bootloaders' check.
struct ReadsFail<'a> {
    flash: &'a mut StateFlash,
    from: u32,
}

impl ErrorType for ReadsFail<'_> {
    type Error = RamFlashError;
}

impl ReadNorFlash for ReadsFail<'_> {
    const READ_SIZE: usize = <StateFlash as ReadNorFlash>::READ_SIZE;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        if offset >= self.from {
            return Err(RamFlashError::PowerCut);
        }
        self.flash.read(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl NorFlash for ReadsFail<'_> {
    const WRITE_SIZE: usize = <StateFlash as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = <StateFlash as NorFlash>::ERASE_SIZE;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.flash.erase(from, to)
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.flash.write(offset, bytes)
    }
}

/// The bootloaders fail closed (stm32 review D2, N5; security review finding 10): a state whose
/// words cannot be read is no "nothing to do", whether the swap word itself or the progress
/// words behind it fail; the bootloader then neither swaps nor starts anything.
#[test]
fn a_state_that_cannot_be_read_is_neither_a_swap_nor_nothing() {
    let (old, new) = (image(1, 3000), image(2, 3001));
    let public = key().verifying_key().to_bytes();
    let mut m = module_with(&old);
    let file = signed(&new, 0xA101, &key());
    let (answers, _) = session(&mut m.dfu, &mut m.state, session_bytes(PASSWORD, &file, None));
    assert_eq!(answers, [0, 0]);
    assert_eq!(check_before_swap(&mut m.active, &mut m.dfu, &mut m.state, MANIFEST_AT, &public), BeforeSwap::Verified);
    let word = <StateFlash as NorFlash>::WRITE_SIZE as u32;
    for (what, from) in [("the swap word", 0), ("the progress words", word), ("the first progress index", 2 * word)] {
        let mut state = ReadsFail { flash: &mut m.state, from };
        assert_eq!(
            check_before_swap(&mut m.active, &mut m.dfu, &mut state, MANIFEST_AT, &public),
            BeforeSwap::Unreadable,
            "{what}"
        );
    }
    // Nothing asked for, and unreadable: still no "nothing to do".
    let mut fresh = module_with(&old);
    let mut state = ReadsFail { flash: &mut fresh.state, from: 0 };
    assert_eq!(
        check_before_swap(&mut fresh.active, &mut fresh.dfu, &mut state, MANIFEST_AT, &public),
        BeforeSwap::Unreadable
    );
}

#[test]
fn no_update_while_the_factory_password_is_in_force() {
    let (old, new) = (image(1, 3000), image(2, 3001));
    let mut m = module_with(&old);
    let file = signed(&new, 0xA101, &key());
    let plan = session_bytes(remodaq_protocol::auth::FACTORY_PASSWORD, &file, None);
    let settings = S { password: Credential::FACTORY, ..S::defaults() };
    let (answers, outcome) = sessions_with(settings, &mut m.dfu, &mut m.state, vec![plan]).0.remove(0);
    assert_eq!((answers, outcome), (vec![Status::SetPasswordFirst as u8], Outcome::NotUpdated));
    assert_eq!((m.boot(None), m.running(&old, &new)), (Ok(State::Boot), "old"));
}

#[test]
fn refusals_change_nothing() {
    let (old, new) = (image(1, 3000), image(2, 2048));
    let file = signed(&new, 0xA101, &key());
    /// What is refused, what the PC sends, what the module answers.
    type Case = (&'static str, Plan, Vec<u8>);
    let cases: Vec<Case> = vec![
        ("wrong password", session_bytes("guess", &file, None), vec![Status::WrongPassword as u8]),
        (
            "signed with another key",
            session_bytes(PASSWORD, &signed(&new, 0xA101, &SigningKey::from_bytes(&[7; 32])), None),
            vec![0, Status::BadSignature as u8],
        ),
        (
            "a byte changed after signing",
            session_bytes(
                PASSWORD,
                &{
                    let mut f = file.clone();
                    let last = f.len() - 1;
                    f[last] ^= 1;
                    f
                },
                None,
            ),
            vec![0, Status::BadSignature as u8],
        ),
        ("truncated", session_bytes(PASSWORD, &file, Some(file.len() - 100)), vec![0]),
        ("header only", session_bytes(PASSWORD, &file, Some(HEADER_LEN)), vec![0]),
        ("too large", session_bytes(PASSWORD, &signed(&image(3, 4 * PAGE + 4), 1, &key()), None), vec![3]),
        (
            "another model",
            session_bytes(
                PASSWORD,
                &{
                    let mut f = file.clone();
                    f[6..8].copy_from_slice(&0x8318u16.to_be_bytes());
                    f
                },
                None,
            ),
            vec![3],
        ),
    ];
    for (what, bytes, want) in cases {
        let mut m = module_with(&old);
        let (answers, outcome) = session(&mut m.dfu, &mut m.state, bytes);
        assert_eq!((answers, outcome), (want, Outcome::NotUpdated), "{what}");
        assert_eq!(m.boot(None), Ok(State::Boot), "{what}: no swap");
        assert_eq!(m.running(&old, &new), "old", "{what}");
        // And a full session afterwards works (a cut transfer can be started again).
        let (answers, _) = session(&mut m.dfu, &mut m.state, session_bytes(PASSWORD, &file, None));
        assert_eq!(answers, [0, 0], "{what}: then a good session");
        assert_eq!(m.boot(None), Ok(State::Swap));
        assert_eq!(m.running(&old, &new), "new");
    }
}

#[test]
fn a_cut_session_then_a_new_one_on_the_same_running_module() {
    // The module keeps one updater: a session cut part way, then a complete one, must give the
    // new image exactly (the partition is erased again at each session's start).
    let (old, new) = (image(1, 3000), image(2, 3500));
    let file = signed(&new, 0xA101, &key());
    let other = signed(&image(9, 3500), 0xA101, &key());
    let mut m = module_with(&old);
    let results = sessions(
        &mut m.dfu,
        &mut m.state,
        vec![
            // Cut inside the first page, after two chunks were written to it: the next session
            // starts in the page written last.
            session_bytes(PASSWORD, &other, Some(HEADER_LEN + 2048 + 100)),
            session_bytes(PASSWORD, &file, Some(2900)),
            session_bytes(PASSWORD, &file, None),
        ],
    );
    let answers: Vec<Vec<u8>> = results.iter().map(|(a, _)| a.clone()).collect();
    assert_eq!(answers, [vec![0], vec![0], vec![0, 0]]);
    assert_eq!(results[2].1, Outcome::Updated { version: 0xA101 });
    assert_eq!(m.boot(None), Ok(State::Swap));
    assert_eq!(m.running(&old, &new), "new");
}

#[test]
fn power_cut_at_every_write_and_erase_of_the_marking() {
    let (old, new) = (image(1, 4 * PAGE), image(2, 4 * PAGE));
    let file = signed(&new, 0xA102, &key());
    let mut booted = std::collections::BTreeMap::new();
    for cut in 0.. {
        assert!(cut < 100_000, "the update never completed");
        let mut m = module_with(&old);
        m.state.set_budget(Some(cut));
        let (answers, outcome) = session(&mut m.dfu, &mut m.state, session_bytes(PASSWORD, &file, None));
        m.state.set_budget(None);
        let state = m.boot(None).expect("boots after the cut");
        let running = m.running(&old, &new);
        assert!(
            (state == State::Boot && running == "old") || (state == State::Swap && running == "new"),
            "cut {cut}: {state:?} with the {running} image"
        );
        *booted.entry(running).or_insert(0) += 1;
        if outcome != Outcome::NotUpdated {
            assert_eq!(answers, [0, 0]);
            break;
        }
    }
    eprintln!("cuts while marking the update: {booted:?}");
    assert!(booted.get("old").copied().unwrap_or(0) > 0);

    // Cut while the firmware streams into the update partition: refused, the old one boots.
    let mut cuts = 0;
    for cut in 0.. {
        assert!(cut < 100_000, "the update never completed");
        let mut m = module_with(&old);
        m.dfu.set_budget(Some(cut));
        let (answers, outcome) = session(&mut m.dfu, &mut m.state, session_bytes(PASSWORD, &file, None));
        m.dfu.set_budget(None);
        if outcome != Outcome::NotUpdated {
            break;
        }
        // Cut while erasing the partition at the start, or while writing the firmware.
        assert!(
            answers == [Status::StoreFailed as u8] || answers == [0, Status::StoreFailed as u8],
            "cut {cut}: {answers:?}"
        );
        assert_eq!((m.boot(None), m.running(&old, &new)), (Ok(State::Boot), "old"), "cut {cut}");
        cuts += 1;
    }
    eprintln!("cuts while writing the update partition: {cuts}, each left the old image");
    assert!(cuts > 1000);
}

#[test]
fn power_cut_at_every_write_and_erase_of_the_swap_and_the_revert() {
    let (old, new) = (image(1, 4 * PAGE), image(2, 4 * PAGE - 8));
    let mut marked = module_with(&old);
    let (answers, _) =
        session(&mut marked.dfu, &mut marked.state, session_bytes(PASSWORD, &signed(&new, 3, &key()), None));
    assert_eq!(answers, [0, 0]);

    // The swap, cut after every operation, then the power comes back: the new image boots
    // (on trial).
    let mut swap_ops = 0;
    for cut in 0.. {
        let mut m = marked.copy();
        match m.boot(Some(cut)) {
            Ok(state) => {
                assert_eq!((state, m.running(&old, &new)), (State::Swap, "new"));
                swap_ops = cut;
                break;
            }
            Err(_) => {
                assert_eq!(m.boot(None), Ok(State::Swap), "cut {cut}: the swap completes at the next start");
                assert_eq!(m.running(&old, &new), "new", "cut {cut}");
            }
        }
    }
    let mut swapped = marked.copy();
    assert_eq!(swapped.boot(None), Ok(State::Swap));

    // The new image never confirms: at the next start (the watchdog's reset) the bootloader
    // reverts, cut after every operation too: the old image boots.
    let mut revert_ops = 0;
    for cut in 0.. {
        let mut m = swapped.copy();
        match m.boot(Some(cut)) {
            Ok(state) => {
                // prepare_boot answers the state it found (Swap) and leaves Revert behind.
                assert_eq!((state, m.running(&old, &new)), (State::Swap, "old"), "reverted");
                assert_eq!(m.boot(None), Ok(State::Revert), "the next start knows it reverted");
                assert_eq!(m.running(&old, &new), "old");
                revert_ops = cut;
                break;
            }
            Err(_) => {
                let state = m.boot(None).expect("boots");
                assert_eq!(m.running(&old, &new), "old", "cut {cut}: {state:?}");
            }
        }
    }
    eprintln!("power cut at each of {swap_ops} operations of the swap and {revert_ops} of the revert");
    assert!(swap_ops > 100 && revert_ops > 100, "every page copy was cut: {swap_ops} / {revert_ops}");
}

/// Counts the erases that reach the update partition (async, as the boards' flashes).
struct CountingErases<'a> {
    flash: &'a mut Dfu,
    erases: Vec<(u32, u32)>,
}

impl embedded_storage_async::nor_flash::ErrorType for CountingErases<'_> {
    type Error = RamFlashError;
}

impl embedded_storage_async::nor_flash::ReadNorFlash for CountingErases<'_> {
    const READ_SIZE: usize = 1;
    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        ReadNorFlash::read(self.flash, offset, bytes)
    }
    fn capacity(&self) -> usize {
        ReadNorFlash::capacity(self.flash)
    }
}

impl embedded_storage_async::nor_flash::NorFlash for CountingErases<'_> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = PAGE;
    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.erases.push((from, to));
        NorFlash::erase(self.flash, from, to)
    }
    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        NorFlash::write(self.flash, offset, bytes)
    }
}

/// Issue #21: a session erases each sector of the update partition it writes exactly once,
/// one sector per erase (a settings write waits for one sector's erase at most), and no other:
/// a 2-page image and the manifest's page. A cut session's leftovers in a sector are erased
/// again by the next session before it writes there.
#[test]
fn a_session_erases_each_sector_it_writes_once() {
    let (old, new) = (image(1, 3000), image(2, PAGE + 100));
    let mut m = module_with(&old);
    let file = signed(&new, 0xA101, &key());
    let settings = S { password: credential(), ..S::defaults() };
    let store = store_with(None);
    let map = Mutex::<NoopRawMutex, _>::new(Live(settings));
    let mut service = UpdateService::new(MODEL, [2, 0, 0, 0, 0, 1], 4 * PAGE as u32);
    let mut aligned = [0u8; 4];
    let mut dfu = CountingErases { flash: &mut m.dfu, erases: vec![] };
    {
        let mut target = updater(&mut dfu, &mut m.state, &mut aligned);
        // A session cut half-way through the first page, then a whole one.
        for plan in [session_bytes(PASSWORD, &file, Some(HEADER_LEN + 2000)), session_bytes(PASSWORD, &file, None)] {
            let mut pc = Pc::new(plan);
            let (_turn, now) = session_time();
            block_on(service.session(&mut pc, [127, 0, 0, 1], now, &map, &store, &mut target));
        }
    }
    let page = PAGE as u32;
    assert_eq!(
        dfu.erases,
        [(0, page), (0, page), (page, 2 * page), (4 * page, 5 * page)],
        "the cut session erased page 0; the whole one pages 0 and 1 and the manifest's page 4, each once"
    );
    assert_eq!(m.boot(None), Ok(State::Swap));
    assert_eq!(m.running(&old, &new), "new", "the image written over the cut session's leftovers is intact");
}

/// Issue #21, `confirm()` in each state the bootloader leaves:
/// - Boot: nothing to do;
/// - Swap, self-test passing: confirmed, the pending counter becomes the module's;
/// - Swap, self-test failing: not passed when the trial ends (the caller restarts), still Swap,
///   and the next start reverts;
/// - Revert: confirmed at once without asking the self-test (a failing one: the old image's
///   front end is broken too), the pending counter dropped; no restart, and a further update
///   is accepted.
#[test]
fn confirm_in_boot_swap_and_revert() {
    use remodaq_update::{confirm, Confirmation, UpdateTarget};
    let (old, new) = (image(1, 3000), image(2, 3001));
    let settings = S { password: credential(), update: Counter { confirmed: 1, pending: 2 }, ..S::defaults() };
    let run = |m: &mut Module, passes: bool| -> (Confirmation, S, u32, bool) {
        let store = store_with(Some(settings));
        let map = Mutex::<CriticalSectionRawMutex, _>::new(Live(settings));
        let mut aligned = [0u8; 4];
        let mut target = updater(&mut m.dfu, &mut m.state, &mut aligned);
        let asked = Cell::new(0u32);
        let self_test = || {
            asked.set(asked.get() + 1);
            passes
        };
        let started = std::time::Instant::now();
        let result = block_on(confirm(&mut target, &map, &store, self_test, embassy_time::Duration::from_millis(300)));
        let waited_trial = started.elapsed() >= std::time::Duration::from_millis(300);
        let accepts_update = block_on(target.begin()).is_ok();
        let after = block_on(map.lock()).0;
        assert_eq!(accepts_update, result != Confirmation::NotPassed, "{result:?}: a further update accepted");
        (result, after, asked.get(), waited_trial)
    };
    // Boot.
    let mut m = module_with(&old);
    let (result, after, asked, _) = run(&mut m, false);
    assert_eq!((result, after.update, asked), (Confirmation::Confirmed, settings.update, 0), "Boot");

    // An update marked and swapped in: Swap.
    let updated = || {
        let mut m = module_with(&old);
        let (answers, outcome) =
            session(&mut m.dfu, &mut m.state, session_bytes(PASSWORD, &signed(&new, 0xA101, &key()), None));
        assert_eq!((answers, outcome), (vec![0, 0], Outcome::Updated { version: 0xA101 }));
        assert_eq!(m.boot(None), Ok(State::Swap));
        m
    };
    let mut m = updated();
    let (result, after, asked, _) = run(&mut m, true);
    assert_eq!((result, asked), (Confirmation::Passed, 1), "Swap, passing");
    assert_eq!(after.update, Counter { confirmed: 2, pending: 0 }, "Swap, passing: counter 2 confirmed");
    assert_eq!((m.boot(None), m.running(&old, &new)), (Ok(State::Boot), "new"), "confirmed: it stays");

    let mut m = updated();
    let (result, after, asked, waited) = run(&mut m, false);
    assert_eq!(result, Confirmation::NotPassed, "Swap, failing");
    assert!(waited && asked >= 2, "the whole trial, asking the self-test again ({asked} times)");
    assert_eq!(after.update, settings.update, "Swap, failing: counters unchanged");
    // The restart: the bootloader finds the swapped image unconfirmed (it returns the state it
    // found, Swap) and reverts, leaving Revert for the application.
    assert_eq!((m.boot(None), m.running(&old, &new)), (Ok(State::Swap), "old"), "reverted at the next start");

    let (result, after, asked, waited) = run(&mut m, false);
    assert_eq!((result, asked, waited), (Confirmation::Reverted, 0, false), "Revert: at once, no self-test");
    assert_eq!(after.update, Counter { confirmed: 1, pending: 0 }, "Revert: the pending counter dropped");
    // Every later start: Boot, the old image, no trial (so no restart).
    for start in 0..3 {
        assert_eq!((m.boot(None), m.running(&old, &new)), (Ok(State::Boot), "old"), "start {start}");
        let (result, _, asked, _) = run(&mut m, false);
        assert_eq!((result, asked), (Confirmation::Confirmed, 0), "start {start}: nothing to confirm");
    }
}

/// Security review finding 7: a page in the administrator's browser can make it connect to
/// the update port and send an HTTP request, whose bytes the module once read as a nonce and a
/// proof (spending the guessing budget). A stream that does not open with the session's
/// magic and version (`OPENING`, with NUL bytes no HTTP request line has) is closed after its
/// first 8 bytes: no greeting, nothing read as a proof, no failure counted.
#[test]
fn a_browser_request_is_closed_before_any_proof() {
    use remodaq_shared::diagnostics::DIAGNOSTICS;
    use remodaq_shared::protocol::diag::Diag;
    let settings = S { password: credential(), ..S::defaults() };
    let store = store_with(Some(settings));
    let map = Mutex::<CriticalSectionRawMutex, _>::new(Live(settings));
    let mut m = module_with(&image(1, 3000));
    let mut service = UpdateService::new(MODEL, [2, 0, 0, 0, 0, 1], 4 * PAGE as u32);
    let body = vec![0x5A; 200];
    let requests: [Vec<u8>; 4] = [
        [&b"POST /update HTTP/1.1\r\nHost: 192.168.0.1:8301\r\nContent-Length: 200\r\n\r\n"[..], &body].concat(),
        b"GET / HTTP/1.1\r\nHost: 192.168.0.1:8301\r\n\r\n".to_vec(),
        b"OPTIONS * HTTP/1.1\r\n\r\n".to_vec(),
        // The opening of another version.
        [&b"RDAQ\x00UP\x02"[..], &[0xC0; 16], &[0; 32]].concat(),
    ];
    for request in requests {
        let (turn, now) = session_time();
        let failures = DIAGNOSTICS.read(Diag::AuthFailures, 0);
        let mut aligned = [0u8; 4];
        let mut target = updater(&mut m.dfu, &mut m.state, &mut aligned);
        let mut io = Script::new(&[]);
        io.incoming = request.chunks(7).map(<[u8]>::to_vec).collect();
        let outcome = block_on(service.session(&mut io, [127, 0, 0, 1], now, &map, &store, &mut target));
        let text = String::from_utf8_lossy(&request[..8]).into_owned();
        assert_eq!(outcome, Outcome::NotUpdated, "{text}");
        assert!(io.outgoing.is_empty(), "{text}: answered {:?}", io.outgoing);
        let unread: usize = io.incoming.iter().map(Vec::len).sum();
        assert_eq!(unread, request.len() - 8, "{text}: read beyond its first 8 bytes");
        assert_eq!(DIAGNOSTICS.read(Diag::AuthFailures, 0), failures, "{text}: a proof checked");
        drop(turn);
    }
}

/// Security review finding 11a: the anti-rollback counter is committed before the new image
/// is confirmed. A settings store that cannot take the commit (as a power cut between the two
/// would leave it) confirms nothing: the trial ends unpassed, the image stays unconfirmed and
/// the next start reverts, instead of an image confirmed under the old counter for good.
#[test]
fn a_counter_that_cannot_be_stored_confirms_no_image() {
    use remodaq_update::{confirm, Confirmation};
    let (old, new) = (image(1, 3000), image(2, 3001));
    let settings = S { password: credential(), update: Counter { confirmed: 1, pending: 0 }, ..S::defaults() };
    let mut m = module_with(&old);
    let (answers, outcome) =
        session(&mut m.dfu, &mut m.state, session_bytes(PASSWORD, &signed(&new, 0xA101, &key()), None));
    assert_eq!((answers, outcome), (vec![0, 0], Outcome::Updated { version: 0xA101 }));
    assert_eq!(m.boot(None), Ok(State::Swap));
    // The pending counter as the session left it, then a store whose commits all fail.
    let pending = S { update: Counter { confirmed: 1, pending: 2 }, ..settings };
    let store = store_with(Some(pending));
    store.try_lock().expect("free").flash_mut().set_budget(Some(0));
    let map = Mutex::<CriticalSectionRawMutex, _>::new(Live(pending));
    let mut aligned = [0u8; 4];
    let mut target = updater(&mut m.dfu, &mut m.state, &mut aligned);
    let result = block_on(confirm(&mut target, &map, &store, || true, embassy_time::Duration::from_millis(200)));
    assert_eq!(result, Confirmation::NotPassed, "the self-test passed, the counter could not be stored");
    assert_eq!(block_on(map.lock()).0.update, pending.update, "the counters as they were");
    assert_eq!((m.boot(None), m.running(&old, &new)), (Ok(State::Swap), "old"), "reverted at the next start");
}

/// Uploads `file` through the web console's steps (`remodaq_web::firmware`) to a module
/// with `settings`, chunk by chunk in order; each step's result, and the settings after.
#[cfg(feature = "web")]
fn web_upload(
    m: &mut Module,
    settings: S,
    file: &[u8],
    steps: impl FnOnce(&[u8]) -> Vec<WebStep>,
) -> (Vec<Result<WebDone, Status>>, S) {
    let store = store_with(Some(settings));
    let map = Mutex::<NoopRawMutex, _>::new(Live(settings));
    let mut aligned = [0u8; 4];
    let mut target = updater(&mut m.dfu, &mut m.state, &mut aligned);
    let mut service = UpdateService::new(MODEL, [2, 0, 0, 0, 0, 1], 4 * PAGE as u32);
    let done = steps(file).iter().map(|step| block_on(service.web_step(step, &map, &store, &mut target))).collect();
    let after = block_on(map.lock()).0;
    (done, after)
}

/// The steps of a whole upload: the header, each chunk in order, the finish.
#[cfg(feature = "web")]
fn web_steps(file: &[u8]) -> Vec<WebStep> {
    let (header, firmware) = file.split_at(HEADER_LEN);
    let mut steps = vec![WebStep::Begin(header.try_into().unwrap())];
    for (i, chunk) in firmware.chunks(WEB_CHUNK).enumerate() {
        let mut data = [0u8; WEB_CHUNK];
        data[..chunk.len()].copy_from_slice(chunk);
        steps.push(WebStep::Write { offset: (i * WEB_CHUNK) as u32, len: chunk.len(), data });
    }
    steps.push(WebStep::Finish);
    steps
}

#[cfg(feature = "web")]
#[test]
fn an_upload_through_the_web_console_is_checked_as_a_session_is() {
    let (old, new) = (image(1, 3000), image(2, 3001));
    let settings = S { password: credential(), ..S::defaults() };
    // The whole image, in order: verified, marked (the counter kept as pending), swapped in.
    let mut m = module_with(&old);
    let file = signed_as(&new, MODEL, 0xA101, 7, &key());
    let (done, after) = web_upload(&mut m, settings, &file, web_steps);
    let header = Header::decode(file[..HEADER_LEN].try_into().unwrap()).unwrap();
    assert_eq!(done.first(), Some(&Ok(WebDone::Begun(header))));
    assert_eq!(done.last(), Some(&Ok(WebDone::Updated(header))));
    assert_eq!(done[done.len() - 2], Ok(WebDone::Written(3001)), "every byte written");
    assert_eq!(after.update, Counter { confirmed: 0, pending: 7 });
    assert_eq!(m.boot(None), Ok(State::Swap));
    assert_eq!(m.running(&old, &new), "new");

    // A chunk out of order or of the wrong length is refused (Invalid), nothing written; the
    // finish of an image not all sent too; nothing is marked.
    let mut m = module_with(&old);
    let file = signed(&new, 0xA101, &key());
    let skip = |file: &[u8]| {
        let mut steps = web_steps(file);
        steps.remove(2); // the second chunk
        steps
    };
    let (done, _) = web_upload(&mut m, settings, &file, skip);
    assert_eq!(done[1], Ok(WebDone::Written(WEB_CHUNK as u32)));
    assert!(done[2..].iter().all(|d| *d == Err(Status::Invalid)), "{done:?}");
    let short = |file: &[u8]| {
        let mut steps = web_steps(file);
        if let Some(WebStep::Write { len, .. }) = steps.get_mut(1) {
            *len -= 1;
        }
        steps
    };
    let (done, _) = web_upload(&mut m, settings, &file, short);
    assert_eq!(done[1], Err(Status::Invalid));
    assert_eq!(m.boot(None), Ok(State::Boot), "nothing marked");
    assert_eq!(m.running(&old, &new), "old");

    // A changed byte of firmware: the signature check fails at the finish, nothing marked.
    let mut altered = file.clone();
    altered[HEADER_LEN + 1000] ^= 1;
    let (done, _) = web_upload(&mut m, settings, &altered, web_steps);
    assert_eq!(done.last(), Some(&Err(Status::BadSignature)));
    assert_eq!(m.boot(None), Ok(State::Boot));
    // Another key's image, the other model's, an older counter: refused at the header.
    let other_key = signed(&new, 0xA101, &SigningKey::from_bytes(&[0x11; 32]));
    let (done, _) = web_upload(&mut m, settings, &other_key, web_steps);
    assert_eq!(done.last(), Some(&Err(Status::BadSignature)));
    let other_model = signed_as(&new, 0x8318, 0xA101, 0, &key());
    let (done, _) = web_upload(&mut m, settings, &other_model, web_steps);
    assert_eq!(done[0], Err(Status::Invalid));
    let newer = S { update: Counter { confirmed: 8, pending: 0 }, ..settings };
    let (done, after) = web_upload(&mut m, newer, &signed_as(&new, MODEL, 0xA101, 7, &key()), web_steps);
    assert_eq!(done[0], Err(Status::Downgrade));
    assert_eq!(after.update, Counter { confirmed: 8, pending: 0 }, "the counters untouched");
    assert_eq!(m.boot(None), Ok(State::Boot), "nothing marked");
    assert_eq!(m.running(&old, &new), "old");
}

/// Attack: a connection to the update service, or a session with a wrong password, meant to
/// end an upload through the console under way. Refused: only a session that proved the
/// password and began writing the partition ends it (docs/web.md, "Firmware").
#[cfg(feature = "web")]
#[test]
fn only_a_session_that_begins_writing_ends_an_upload_of_the_console() {
    let (old, new) = (image(1, 3000), image(2, 3001));
    let settings = S { password: credential(), ..S::defaults() };
    let mut m = module_with(&old);
    let file = signed(&new, 0xA101, &key());
    let steps = web_steps(&file);
    let store = store_with(Some(settings));
    let map = Mutex::<NoopRawMutex, _>::new(Live(settings));
    let mut aligned = [0u8; 4];
    let mut target = updater(&mut m.dfu, &mut m.state, &mut aligned);
    let mut service = UpdateService::new(MODEL, [2, 0, 0, 0, 0, 1], 4 * PAGE as u32);
    let step = |service: &mut UpdateService, target: &mut _, i: usize| {
        block_on(service.web_step(&steps[i], &map, &store, target))
    };
    assert!(matches!(step(&mut service, &mut target, 0), Ok(WebDone::Begun(_))));
    assert_eq!(step(&mut service, &mut target, 1), Ok(WebDone::Written(WEB_CHUNK as u32)));

    // A session with a wrong password: refused (status 1), the upload goes on.
    let mut wrong = Pc::new(session_bytes("not the password", &file, None));
    let (turn, now) = session_time();
    let outcome = block_on(service.session(&mut wrong, [127, 0, 0, 66], now, &map, &store, &mut target));
    drop(turn);
    assert_eq!((outcome, wrong.io.outgoing.get(GREETING_LEN..)), (Outcome::NotUpdated, Some(&[1u8][..])));
    assert_eq!(step(&mut service, &mut target, 2), Ok(WebDone::Written(2 * WEB_CHUNK as u32)));

    // A session with the password that begins writing, then is cut: the console's upload ended
    // (its bytes overwritten), its next chunk told so, nothing marked.
    let mut cut = Pc::new(session_bytes(PASSWORD, &file, Some(HEADER_LEN + 100)));
    let (turn, now) = session_time();
    let outcome = block_on(service.session(&mut cut, [127, 0, 0, 1], now, &map, &store, &mut target));
    drop(turn);
    assert_eq!(outcome, Outcome::NotUpdated);
    assert_eq!(step(&mut service, &mut target, 3), Ok(WebDone::NoUpload));
    assert_eq!(step(&mut service, &mut target, steps.len() - 1), Ok(WebDone::NoUpload));
    assert_eq!((m.boot(None), m.running(&old, &new)), (Ok(State::Boot), "old"));
}

/// A step's answer goes to its own asker only. An asker that gave up (its connection cut
/// while the update task worked) leaves no answer for the next one, and its step, if not
/// taken yet, is never carried out.
#[cfg(feature = "web")]
#[test]
fn a_web_step_answers_its_own_asker_only() {
    use core::pin::pin;
    use core::task::Poll;
    use embassy_futures::poll_once;
    use remodaq_shared::upload::WebLink;
    let link = WebLink::new();
    let write = |len| WebStep::Write { offset: 0, len, data: [0; WEB_CHUNK] };
    assert!(!link.is_served());
    let mut next = pin!(link.next());
    assert!(poll_once(next.as_mut()).is_pending());
    assert!(link.is_served(), "an update task waits for steps");

    // Asker 1's step is taken by the task; asker 1 gives up before the answer.
    let (first, step) = {
        let mut one = pin!(link.ask(WebStep::Finish));
        assert!(poll_once(one.as_mut()).is_pending());
        let Poll::Ready(taken) = poll_once(next.as_mut()) else { panic!("the task takes the step") };
        taken
    };
    assert!(matches!(step, WebStep::Finish));
    // Asker 2 asks; the answer to asker 1's step arrives first: not asker 2's.
    let mut two = pin!(link.ask(write(7)));
    assert!(poll_once(two.as_mut()).is_pending());
    link.answer(first, Ok(WebDone::NoUpload));
    assert!(poll_once(two.as_mut()).is_pending(), "asker 1's answer is not asker 2's");
    let Poll::Ready((second, WebStep::Write { len: 7, .. })) = poll_once(pin!(link.next())) else {
        panic!("the task takes asker 2's step")
    };
    assert_ne!(first, second);
    link.answer(second, Ok(WebDone::Written(7)));
    assert_eq!(poll_once(two.as_mut()), Poll::Ready(Some(Ok(WebDone::Written(7)))));

    // Asker 3 asks and gives up before the task looks: its step is never carried out; asker
    // 4's is the next the task sees.
    {
        let mut three = pin!(link.ask(write(3)));
        assert!(poll_once(three.as_mut()).is_pending());
    }
    let mut four = pin!(link.ask(write(4)));
    assert!(poll_once(four.as_mut()).is_pending());
    let Poll::Ready((_, WebStep::Write { len, .. })) = poll_once(pin!(link.next())) else {
        panic!("the task takes a step")
    };
    assert_eq!(len, 4, "asker 3's step is not carried out");
}

/// docs/web.md, "Firmware": after a finish verified and marked, the console's connection task
/// restarts the module once its answer is sent; "should that answer not get out, the update
/// task restarts the module itself 3 s after the mark". Here the board's update task
/// (`remodaq_update::embassy::serve_sessions`, on an embassy-net stack with no wire: nobody connects to the
/// update port) takes the console's steps through `update::WEB`, and no connection task
/// restarts anything (its answer was lost): the update task restarts the module 3 s after the
/// good finish, and not after a refused one. Needs the features `web` and `embassy-net`
/// (`cargo test -p remodaq-shared --features web,embassy-net --test update`).
#[cfg(all(feature = "web", feature = "embassy-net"))]
#[test]
fn the_update_task_restarts_3_s_after_a_finish_whose_answer_was_lost() {
    use std::sync::Mutex as StdMutex;
    use std::time::{Duration, Instant};

    use embassy_futures::select::{select, Either};
    use embassy_net_driver::{Capabilities, Driver, HardwareAddress, LinkState};
    use remodaq_net::EmbassyNet;
    use remodaq_shared::board::Effect;
    use remodaq_shared::upload::WEB;

    /// A network interface on which nothing ever arrives or leaves.
    struct NoWire;
    struct Nothing;
    impl embassy_net_driver::RxToken for Nothing {
        fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, f: F) -> R {
            f(&mut [])
        }
    }
    impl embassy_net_driver::TxToken for Nothing {
        fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, len: usize, f: F) -> R {
            f(&mut vec![0; len])
        }
    }
    impl Driver for NoWire {
        type RxToken<'a> = Nothing;
        type TxToken<'a> = Nothing;
        fn receive(&mut self, _: &mut core::task::Context) -> Option<(Nothing, Nothing)> {
            None
        }
        fn transmit(&mut self, _: &mut core::task::Context) -> Option<Nothing> {
            None
        }
        fn link_state(&mut self, _: &mut core::task::Context) -> LinkState {
            LinkState::Down
        }
        fn capabilities(&self) -> Capabilities {
            let mut caps = Capabilities::default();
            caps.max_transmission_unit = 1514;
            caps
        }
        fn hardware_address(&self) -> HardwareAddress {
            HardwareAddress::Ethernet([2, 0, 0, 0, 0, 1])
        }
    }

    /// The board's restart: when it was asked for (it never returns to the update task).
    struct Restarts(StdMutex<Vec<Instant>>);
    impl remodaq_shared::board::Effects for Restarts {
        async fn apply(&self, effect: Effect) {
            if matches!(effect, Effect::Restart) {
                self.0.lock().unwrap().push(Instant::now());
            }
        }
    }

    let (old, new) = (image(1, 3000), image(2, 3001));
    let settings = S { password: credential(), ..S::defaults() };
    let mut m = module_with(&old);
    let resources = Box::leak(Box::new(embassy_net::StackResources::<4>::new()));
    let (stack, _runner) = embassy_net::new(NoWire, embassy_net::Config::default(), resources, 1);
    let net: &'static EmbassyNet<Restarts> =
        Box::leak(Box::new(EmbassyNet { stack, port: 8000, effects: Restarts(StdMutex::new(Vec::new())) }));
    let map: &'static remodaq_shared::board::Shared<Live> = Box::leak(Box::new(Mutex::new(Live(settings))));
    let store: &'static Mutex<CriticalSectionRawMutex, _> = Box::leak(Box::new(store_with(Some(settings))));
    let mut aligned = [0u8; 4];
    let mut target = updater(&mut m.dfu, &mut m.state, &mut aligned);
    let mut service = UpdateService::new(MODEL, [2, 0, 0, 0, 0, 1], 4 * PAGE as u32);
    let restarts = || net.effects.0.lock().unwrap().clone();

    // The console's side: each step asked for as its connection tasks would, the answers
    // taken, and nobody restarting the module.
    let console = async {
        let upload = async |file: &[u8]| {
            let mut last = None;
            for step in web_steps(file) {
                last = WEB.ask(step).await;
            }
            (last, Instant::now())
        };
        // A finish refused (a changed byte: the signature does not match): no restart.
        let mut altered = signed(&new, 0xA101, &key());
        altered[HEADER_LEN + 1000] ^= 1;
        let (refused, _) = upload(&altered).await;
        assert_eq!(refused, Some(Err(Status::BadSignature)));
        // The good image: verified and marked; its answer is "lost" here.
        let (done, finished) = upload(&signed(&new, 0xA101, &key())).await;
        assert!(matches!(done, Some(Ok(WebDone::Updated(_)))), "{done:?}");
        while restarts().is_empty() && finished.elapsed() < Duration::from_secs(6) {
            embassy_time::Timer::after_millis(20).await;
        }
        finished
    };
    // The update task first: it waits for steps (`WEB.is_served`) before the console asks.
    let update_task = remodaq_update::embassy::serve_sessions(net, map, store, &mut service, &mut target);
    let finished = match futures_executor::block_on(select(update_task, console)) {
        Either::First(never) => never,
        Either::Second(finished) => finished,
    };
    let seen = restarts();
    assert_eq!(seen.len(), 1, "one restart, by the update task, after the good finish only");
    let after = seen[0].duration_since(finished);
    eprintln!("the update task restarted the module {after:?} after the finish was answered");
    // The answer leaves the update task before its 3 s start: the restart comes no earlier than
    // 3 s after it (a moment of scheduling aside), and in time (the machine may be loaded).
    assert!(after >= Duration::from_millis(2950), "restarted {after:?} after the finish, before the 3 s");
    assert!(after <= Duration::from_millis(4500), "restarted only {after:?} after the finish");
    assert_eq!((m.boot(None), m.running(&old, &new)), (Ok(State::Swap), "new"), "the image was marked");
}
