//! The firmware update service (docs/update.md; the codec is `remodaq_protocol::update`,
//! re-exported): one session streams a signed image into the update (DFU) partition with a
//! bounded buffer, then has it verified and marked for the bootloader. A session cut at any
//! point leaves the running image, its state and the settings untouched, and can simply be
//! started again. [`start`] confirms a new image on trial; [`embassy`] (feature `embassy-net`)
//! serves the sessions on an embassy-net socket, and the web console's uploads between them.
#![no_std]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

#[cfg(feature = "embassy-net")]
pub mod embassy;

pub use remodaq_protocol::update::*;

mod boot;
mod io;
mod session;
mod target;
mod trial;

pub use boot::{BootUpdater, HASH_CHUNK, MANIFEST_LEN};
pub use io::STALL;
pub use session::{Outcome, UpdateService, CHUNK};
pub use target::UpdateTarget;
pub use trial::{confirm, self_test_passed, start, Confirmation, TRIAL};
