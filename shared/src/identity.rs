//! Identity: the registers common to both modules (spec §2.1, §3.2, from the protocol crate), and
//! what the image's build fixed: the firmware version and the key updates are verified with.
//!
//! The image crate reads both at build time (boards/update-key.rs: `REMODAQ_FIRMWARE_VERSION`,
//! `REMODAQ_UPDATE_KEY`) and hands them over with [`set_build`] before it starts anything, so that
//! a test image of another version or key rebuilds only the image crate, not every crate under it.
use core::sync::atomic::{AtomicU16, AtomicU8, Ordering};

pub use remodaq_protocol::identity::*;

/// What the image crate's build fixed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Build {
    /// The firmware version reported in 40213 and in INFO.
    pub version: u16,
    /// The public key firmware images must be signed for.
    pub update_key: [u8; 32],
}

static VERSION: AtomicU16 = AtomicU16::new(FIRMWARE_VERSION);
/// Until [`set_build`]: on a PC (this crate's own tests) the repository's test key, the key a
/// simulator built without `REMODAQ_UPDATE_KEY` takes; on a module all zeros, which verifies
/// no image (the image sets its key before it starts any service).
static UPDATE_KEY: [AtomicU8; 32] = {
    let key = if cfg!(target_os = "none") { [0; 32] } else { TEST_UPDATE_KEY };
    let mut bytes = [const { AtomicU8::new(0) }; 32];
    let mut i = 0;
    while i < 32 {
        bytes[i] = AtomicU8::new(key[i]);
        i += 1;
    }
    bytes
};

/// The repository's test key (keys/test-update.key.pub; its secret half is public).
const TEST_UPDATE_KEY: [u8; 32] = hex32(include_str!("../../keys/test-update.key.pub").as_bytes());

/// 64 hex digits (a build error otherwise).
const fn hex32(text: &[u8]) -> [u8; 32] {
    const fn digit(c: u8) -> u8 {
        match c {
            b'0'..=b'9' => c - b'0',
            b'a'..=b'f' => c - b'a' + 10,
            b'A'..=b'F' => c - b'A' + 10,
            _ => panic!("keys/test-update.key.pub: not hex"),
        }
    }
    assert!(text.len() >= 64, "keys/test-update.key.pub: 64 hex digits");
    let mut key = [0; 32];
    let mut i = 0;
    while i < 32 {
        key[i] = digit(text[2 * i]) << 4 | digit(text[2 * i + 1]);
        i += 1;
    }
    key
}

/// Sets what the image's build fixed: by the image, before it starts the module.
pub fn set_build(build: Build) {
    VERSION.store(build.version, Ordering::Relaxed);
    for (byte, value) in UPDATE_KEY.iter().zip(build.update_key) {
        byte.store(value, Ordering::Relaxed);
    }
}

/// The firmware version of this image (40213, INFO).
pub fn firmware_version() -> u16 {
    VERSION.load(Ordering::Relaxed)
}

/// The public key firmware images must be signed for.
pub fn update_key() -> [u8; 32] {
    core::array::from_fn(|i| UPDATE_KEY[i].load(Ordering::Relaxed))
}

/// What a module says about itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Identity {
    /// Module name register value (8318h, 8350h).
    pub model: u16,
    /// Model string.
    pub name: &'static str,
    /// Firmware version register value.
    pub version: u16,
    /// MAC address.
    pub mac: [u8; 6],
    /// The network settings in force since start-up.
    pub running: crate::net::NetConfig,
}
