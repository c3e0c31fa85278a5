//! A connection dropped at its deadline is never dropped in the middle of a settings commit
//! (security review finding 15c: a late request cut between the flash write and the register
//! map's update left the flash with a new password and RAM checking the old one).

use core::cell::Cell;
use core::future::Future;
use core::pin::pin;
use core::task::{Context, Poll};
use std::time::{Duration, Instant};

use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, NoopRawMutex};
use embassy_sync::mutex::Mutex;
use embedded_storage_async::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use remodaq_shared::module::{commit_change, commit_under_way, CommonSettings as _, SettingsAccess};
use remodaq_shared::net::HTTP_PORT;
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::{RecordReader, RecordWriter, Schema, SettingsStore};

/// The settings of a module (only the web port is stored here).
#[derive(Clone, Copy, PartialEq, Debug)]
struct S {
    net: remodaq_shared::net::NetConfig,
    password: remodaq_shared::password::Credential,
    allow: remodaq_shared::access::AllowList,
    http_port: u16,
    update: remodaq_shared::settings::Counter,
}

impl Schema for S {
    const VERSION: u8 = 2;
    fn defaults() -> Self {
        Self {
            net: remodaq_shared::net::NetConfig::FACTORY,
            password: remodaq_shared::password::Credential::FACTORY,
            allow: remodaq_shared::access::AllowList::EMPTY,
            http_port: HTTP_PORT,
            update: Default::default(),
        }
    }
    fn unreadable() -> Self {
        Self::defaults()
    }
    fn encode(&self, w: &mut RecordWriter<'_>) {
        remodaq_shared::net::encode_http_port(self.http_port, w);
    }
    fn decode(_version: u8, r: &RecordReader<'_>) -> Self {
        Self { http_port: remodaq_shared::net::decode_http_port(r), ..Self::defaults() }
    }
}

remodaq_shared::impl_common_settings!(S);

/// The register map's copy of the settings in force.
struct Live(S);

impl SettingsAccess for Live {
    type Settings = S;
    fn settings(&self) -> &S {
        &self.0
    }
    fn committed(&mut self, s: &S) {
        self.0 = *s;
    }
}

type Ram = RamFlash<8192, 1024>;

thread_local! {
    /// Whether the flash's writes may finish (else each waits).
    static OPEN: Cell<bool> = const { Cell::new(true) };
}

/// A flash whose writes wait while the gate is closed: a commit held in its flash write.
struct Gated(Ram);

impl ErrorType for Gated {
    type Error = <Ram as ErrorType>::Error;
}

impl ReadNorFlash for Gated {
    const READ_SIZE: usize = Ram::READ_SIZE;
    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.0.read(offset, bytes).await
    }
    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl NorFlash for Gated {
    const WRITE_SIZE: usize = Ram::WRITE_SIZE;
    const ERASE_SIZE: usize = Ram::ERASE_SIZE;
    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.0.erase(from, to).await
    }
    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        core::future::poll_fn(|cx| {
            if OPEN.with(Cell::get) {
                Poll::Ready(())
            } else {
                cx.waker().wake_by_ref();
                Poll::Pending
            }
        })
        .await;
        self.0.write(offset, bytes).await
    }
}

/// Polls `f` once (no executor: the test decides when to poll).
fn poll_once<F: Future>(f: core::pin::Pin<&mut F>) -> Poll<F::Output> {
    f.poll(&mut Context::from_waker(core::task::Waker::noop()))
}

/// The commits under way are counted module-wide (a static): these tests take turns, or one's
/// commit would be under way while the other looks.
static TURN: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn turn() -> std::sync::MutexGuard<'static, ()> {
    TURN.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

#[test]
fn a_connections_deadline_waits_for_the_commit_under_way() {
    let _turn = turn();
    let map = Mutex::<NoopRawMutex, _>::new(Live(S::defaults()));
    let flash = Gated(Ram::new());
    let store = Mutex::<CriticalSectionRawMutex, _>::new(futures_executor::block_on(SettingsStore::open(
        flash,
        const { SettingsStore::<Gated, S>::config(0..8192) },
    )));
    store.try_lock().expect("free").resume(remodaq_shared::diagnostics::ResetCause::PowerOn, None);

    // A commit held in its flash write: under way.
    OPEN.with(|o| o.set(false));
    let mut commit = pin!(commit_change(&map, &store, |s| s.set_http_port(8080)));
    assert!(poll_once(commit.as_mut()).is_pending());
    assert!(commit_under_way(), "a commit in its flash write is under way");

    // The connection's deadline (50 ms) passes while the commit is held: it does not end.
    let started = Instant::now();
    let mut deadline = pin!(remodaq_web::service::deadline(embassy_time::Duration::from_millis(50)));
    while started.elapsed() < Duration::from_millis(300) {
        assert!(poll_once(deadline.as_mut()).is_pending(), "the deadline ended during a commit");
        std::thread::sleep(Duration::from_millis(5));
    }

    // The flash write ends, the map takes the change, and then the deadline ends.
    OPEN.with(|o| o.set(true));
    assert!(matches!(poll_once(commit.as_mut()), Poll::Ready(Ok(()))));
    assert!(!commit_under_way());
    assert_eq!(map.try_lock().expect("free").settings().http_port(), 8080);
    assert_eq!(store.try_lock().expect("free").get().http_port, 8080, "flash and RAM agree");
    let ended = Instant::now();
    while poll_once(deadline.as_mut()).is_pending() {
        assert!(ended.elapsed() < Duration::from_secs(2), "the deadline never ended after the commit");
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn a_commit_dropped_anyway_is_no_longer_under_way() {
    let _turn = turn();
    let map = Mutex::<NoopRawMutex, _>::new(Live(S::defaults()));
    let store = Mutex::<CriticalSectionRawMutex, _>::new(futures_executor::block_on(SettingsStore::open(
        Gated(Ram::new()),
        const { SettingsStore::<Gated, S>::config(0..8192) },
    )));
    store.try_lock().expect("free").resume(remodaq_shared::diagnostics::ResetCause::PowerOn, None);
    OPEN.with(|o| o.set(false));
    {
        let mut commit = pin!(commit_change(&map, &store, |s| s.set_http_port(8081)));
        assert!(poll_once(commit.as_mut()).is_pending());
        assert!(commit_under_way());
    }
    assert!(!commit_under_way(), "a dropped commit ends its mark");
}
