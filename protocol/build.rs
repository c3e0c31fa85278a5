//! The public key firmware images are verified with (docs/update.md, docs/security.md), by the
//! application and by the bootloaders: the 64 hex digits of the file named by
//! `REMODAQ_UPDATE_KEY`, as `UPDATE_KEY` in `$OUT_DIR/update_key.rs`.
//!
//! Without `REMODAQ_UPDATE_KEY`, an image for a module (`target_os = "none"`) is a build error,
//! unless the build asks for the repository's test key (`keys/test-update.key.pub`, whose
//! secret half is public) with the feature `test-update-key` (the QEMU board, CI). The host
//! build (a simulator, no bootloader, no updates) takes the test key.
use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-env-changed=REMODAQ_UPDATE_KEY");
    let manifest = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").unwrap_or_default());
    let image = std::env::var("CARGO_CFG_TARGET_OS").is_ok_and(|os| os == "none");
    let test_key = std::env::var_os("CARGO_FEATURE_TEST_UPDATE_KEY").is_some();
    let path = match std::env::var_os("REMODAQ_UPDATE_KEY") {
        Some(path) => PathBuf::from(path),
        None if image && !test_key => {
            eprintln!(
                "error: a firmware image needs the public key its updates are signed with.\n  \
                 Make a key pair once (keep the secret half off the build machine):\n    \
                 remodaq keygen vendor.key\n  \
                 then build with\n    \
                 REMODAQ_UPDATE_KEY=$PWD/vendor.key.pub cargo build --release ...\n  \
                 Test builds only (QEMU, CI) may trust the repository's test key, whose secret half is public:\n    \
                 cargo build ... --features test-update-key"
            );
            std::process::exit(1);
        }
        None => {
            if image {
                println!("cargo:warning=this image trusts the repository's TEST update key (feature test-update-key): never ship it");
            }
            manifest.join("../keys/test-update.key.pub")
        }
    };
    println!("cargo:rerun-if-changed={}", path.display());
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("the update key {}: {e} (REMODAQ_UPDATE_KEY names another)", path.display()));
    let text = text.trim();
    let bytes: Vec<u8> =
        (0..text.len() / 2).filter_map(|i| u8::from_str_radix(text.get(2 * i..2 * i + 2)?, 16).ok()).collect();
    assert!(text.len() == 64 && bytes.len() == 32, "the update key {}: not 64 hex digits", path.display());
    let test_path = manifest.join("../keys/test-update.key.pub");
    println!("cargo:rerun-if-changed={}", test_path.display());
    let test_text = std::fs::read_to_string(&test_path).unwrap_or_default();
    let test_text = test_text.trim();
    let test: Vec<u8> = (0..test_text.len() / 2)
        .filter_map(|i| u8::from_str_radix(test_text.get(2 * i..2 * i + 2)?, 16).ok())
        .collect();
    let out = PathBuf::from(std::env::var_os("OUT_DIR").unwrap_or_default()).join("update_key.rs");
    let code = format!(
        "/// The public key firmware images must be signed for (from `{}`).\npub const UPDATE_KEY: [u8; 32] = {bytes:?};\n\
         /// The repository's test key (its secret half is public): a board's image refuses to build with it\n\
         /// unless asked (boards/stm32).\npub const TEST_UPDATE_KEY: &[u8] = &{test:?};\n\
         /// Whether [`UPDATE_KEY`] is the repository's test key.\npub const UPDATE_KEY_IS_TEST_KEY: bool = {};\n",
        path.display(),
        bytes == test
    );
    std::fs::write(&out, code).unwrap_or_else(|e| panic!("{}: {e}", out.display()));
}
