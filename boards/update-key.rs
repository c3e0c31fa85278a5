// The public key firmware images are verified with (docs/update.md, docs/security.md), read by
// the build script of whatever uses it: the image crates (boards/image-build.rs) and the
// bootloaders (boards/*/bootloader/build.rs). Read there, not in a lower crate, so that a build
// with another key rebuilds only the image or the bootloader (issue #36). Included with
// `include!` by those build scripts.
//
// The key is the 64 hex digits of the file named by `REMODAQ_UPDATE_KEY`. Without it, an image
// for a module (`target_os = "none"`) is a build error, unless the build asks for the
// repository's test key (`keys/test-update.key.pub`, whose secret half is public) with
// `test_key` (the feature `test-update-key`: the QEMU board, CI). The host build (a simulator,
// no bootloader, no updates) takes the test key.

/// Writes `$OUT_DIR/update_key.rs` (`UPDATE_KEY`, `UPDATE_KEY_IS_TEST_KEY`). `refuse_without_key`:
/// a target build without `REMODAQ_UPDATE_KEY` and without `test_key` is a build error.
fn write_update_key(refuse_without_key: bool, test_key: bool) {
    use std::path::{Path, PathBuf};
    println!("cargo:rerun-if-env-changed=REMODAQ_UPDATE_KEY");
    let manifest = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").unwrap_or_default());
    // The workspace root: the first directory up that holds keys/.
    let root = manifest.ancestors().find(|dir| dir.join("keys").is_dir()).unwrap_or(&manifest).to_path_buf();
    let test_path = root.join("keys/test-update.key.pub");
    let image = std::env::var("CARGO_CFG_TARGET_OS").is_ok_and(|os| os == "none");
    let path = match std::env::var_os("REMODAQ_UPDATE_KEY") {
        Some(path) => PathBuf::from(path),
        None if image && refuse_without_key && !test_key => {
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
            if image && refuse_without_key {
                println!("cargo:warning=this image trusts the repository's TEST update key (feature test-update-key): never ship it");
            }
            test_path.clone()
        }
    };
    fn read_key(path: &Path) -> Vec<u8> {
        println!("cargo:rerun-if-changed={}", path.display());
        let text = std::fs::read_to_string(path)
            .unwrap_or_else(|e| panic!("the update key {}: {e} (REMODAQ_UPDATE_KEY names another)", path.display()));
        let text = text.trim();
        let bytes: Vec<u8> =
            (0..text.len() / 2).filter_map(|i| u8::from_str_radix(text.get(2 * i..2 * i + 2)?, 16).ok()).collect();
        assert!(text.len() == 64 && bytes.len() == 32, "the update key {}: not 64 hex digits", path.display());
        bytes
    }
    let bytes = read_key(&path);
    let is_test = bytes == read_key(&test_path);
    let out = PathBuf::from(std::env::var_os("OUT_DIR").unwrap_or_default()).join("update_key.rs");
    let code = format!(
        "/// The public key firmware images must be signed for (from `{}`).\npub const UPDATE_KEY: [u8; 32] = {bytes:?};\n\
         /// Whether [`UPDATE_KEY`] is the repository's test key (its secret half is public).\n\
         #[allow(dead_code)]\npub const UPDATE_KEY_IS_TEST_KEY: bool = {is_test};\n",
        path.display().to_string().replace('\\', "/"),
    );
    std::fs::write(&out, code).unwrap_or_else(|e| panic!("{}: {e}", out.display()));
}

/// Writes `$OUT_DIR/firmware_version.rs`: `FIRMWARE_VERSION_OVERRIDE`, the 4 hex digits of
/// `REMODAQ_FIRMWARE_VERSION` (test images of another version, docs/update.md), or `None`; and
/// `SECURITY_COUNTER_OVERRIDE`, the decimal `REMODAQ_SECURITY_COUNTER` (test images of another
/// security counter), or `None`.
#[allow(dead_code)]
fn write_firmware_version() {
    println!("cargo:rerun-if-env-changed=REMODAQ_FIRMWARE_VERSION");
    println!("cargo:rerun-if-env-changed=REMODAQ_SECURITY_COUNTER");
    let counter = std::env::var("REMODAQ_SECURITY_COUNTER").ok().map(|text| {
        text.parse::<u32>().unwrap_or_else(|_| panic!("REMODAQ_SECURITY_COUNTER: a decimal number, not {text:?}"))
    });
    let version = std::env::var("REMODAQ_FIRMWARE_VERSION").ok().map(|text| {
        match u16::from_str_radix(&text, 16) {
            Ok(v) if text.len() == 4 => v,
            _ => panic!("REMODAQ_FIRMWARE_VERSION: 4 hex digits, not {text:?}"),
        }
    });
    let out = std::path::PathBuf::from(std::env::var_os("OUT_DIR").unwrap_or_default()).join("firmware_version.rs");
    let code = format!(
        "/// `REMODAQ_FIRMWARE_VERSION` at build time, if given (docs/update.md).\n\
         const FIRMWARE_VERSION_OVERRIDE: Option<u16> = {version:?};\n\
         /// `REMODAQ_SECURITY_COUNTER` at build time, if given (docs/update.md).\n\
         const SECURITY_COUNTER_OVERRIDE: Option<u32> = {counter:?};\n"
    );
    std::fs::write(&out, code).unwrap_or_else(|e| panic!("{}: {e}", out.display()));
}
