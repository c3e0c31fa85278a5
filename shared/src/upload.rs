//! The web console's firmware upload handed to the update task (feature `web`): the console
//! (`remodaq-web`) asks for one step at a time through [`WEB`], and the update service
//! (`remodaq-update`), between two of its own sessions, carries it out and answers. Here, in the
//! module runtime, so that neither service imports the other.

use embassy_sync::mutex::Mutex;
use embassy_time::{with_timeout, Duration};
use remodaq_protocol::update::{Header, Status, HEADER_LEN};

/// Firmware bytes of one chunk of an upload through the web console (`PUT
/// /api/v1/firmware/{offset}`): a request's head and this fit the console's buffer.
pub const WEB_CHUNK: usize = remodaq_protocol::web::FIRMWARE_CHUNK;

/// A step of an upload through the web console, for the update task ([`WEB`]).
// The steps channel holds one step in static memory, the size of the largest variant whatever
// its shape; there is no heap to box the chunk into.
#[allow(clippy::large_enum_variant)]
pub enum WebStep {
    /// A new upload: the image's header.
    Begin([u8; HEADER_LEN]),
    /// `len` bytes of firmware at `offset`.
    Write {
        /// Where in the image.
        offset: u32,
        /// How many bytes of `data`.
        len: usize,
        /// The bytes.
        data: [u8; WEB_CHUNK],
    },
    /// The whole image is sent: verify and mark it.
    Finish,
}

/// What a step did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WebDone {
    /// The upload of this image began (the partition ready).
    Begun(Header),
    /// Bytes written so far.
    Written(u32),
    /// The image is verified and marked: restart into it.
    Updated(Header),
    /// No upload is under way: a session of the update service began since, or the last step
    /// failed writing or verifying and ended it.
    NoUpload,
}

/// The web console's way to the update task: one step at a time (a lock), carried out between
/// two sessions of the update service. Each step carries a number its answer repeats: an
/// answer to an asker that gave up (its time ran out, its connection was cut) is no answer to
/// the next, and a step nobody waits for any more is not carried out.
pub struct WebLink {
    lock: Mutex<embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex, ()>,
    steps:
        embassy_sync::channel::Channel<embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex, (u32, WebStep), 1>,
    done: embassy_sync::channel::Channel<
        embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex,
        (u32, Result<WebDone, Status>),
        1,
    >,
    served: core::sync::atomic::AtomicBool,
    /// The number of the last step asked for.
    asked: core::sync::atomic::AtomicU32,
    /// The number of the step whose asker waits for it (0: none).
    waiting: core::sync::atomic::AtomicU32,
}

/// The link of this module.
pub static WEB: WebLink = WebLink::new();

/// How long a step may take: a sector erase of the STM32 within a chunk's write (a 128 KiB
/// sector takes 1 to 2 s, the datasheet's flash characteristics), or a whole image's
/// verification. The wait for another asker's step is bounded the same.
pub const WEB_STEP: Duration = Duration::from_secs(8);

/// While an asker waits: when it stops (answered, out of time, or dropped with its
/// connection), its step is no longer wanted.
struct Waiting<'a>(&'a WebLink, u32);

impl Drop for Waiting<'_> {
    fn drop(&mut self) {
        use core::sync::atomic::Ordering;
        let _ = self.0.waiting.compare_exchange(self.1, 0, Ordering::AcqRel, Ordering::Acquire);
        // A step not taken yet is taken back.
        self.0.steps.clear();
    }
}

impl WebLink {
    /// A link with no step asked for.
    pub const fn new() -> Self {
        Self {
            lock: Mutex::new(()),
            steps: embassy_sync::channel::Channel::new(),
            done: embassy_sync::channel::Channel::new(),
            served: core::sync::atomic::AtomicBool::new(false),
            asked: core::sync::atomic::AtomicU32::new(0),
            waiting: core::sync::atomic::AtomicU32::new(0),
        }
    }

    /// Whether an update task takes steps (a board with a bootloader, its image confirmed).
    pub fn is_served(&self) -> bool {
        self.served.load(core::sync::atomic::Ordering::Acquire)
    }

    /// Has the update task carry out `step`; `None` when no task takes it in time (or another
    /// asker's step holds the task that long).
    pub async fn ask(&self, step: WebStep) -> Option<Result<WebDone, Status>> {
        use core::sync::atomic::Ordering;
        if !self.is_served() {
            return None;
        }
        let _one = with_timeout(WEB_STEP, self.lock.lock()).await.ok()?;
        // Never 0, which stands for nobody.
        let number = self.asked.fetch_add(1, Ordering::AcqRel).wrapping_add(1).max(1);
        self.waiting.store(number, Ordering::Release);
        let _waiting = Waiting(self, number);
        with_timeout(WEB_STEP, async {
            self.steps.send((number, step)).await;
            loop {
                let (answered, done) = self.done.receive().await;
                if answered == number {
                    return done;
                }
            }
        })
        .await
        .ok()
    }

    /// The update task: the next step asked for whose asker still waits, and its number.
    pub async fn next(&self) -> (u32, WebStep) {
        self.served.store(true, core::sync::atomic::Ordering::Release);
        loop {
            let (number, step) = self.steps.receive().await;
            if self.waiting.load(core::sync::atomic::Ordering::Acquire) == number {
                return (number, step);
            }
        }
    }

    /// The update task: what step `number` did.
    pub fn answer(&self, number: u32, done: Result<WebDone, Status>) {
        self.done.clear();
        let _ = self.done.try_send((number, done));
    }
}

impl Default for WebLink {
    fn default() -> Self {
        Self::new()
    }
}
