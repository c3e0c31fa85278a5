//! The update key (boards/update-key.rs). Target builds: cortex-m-rt's linker script (which includes this crate's memory.x: the
//! build links from this directory, see boards/ld).
include!("../../update-key.rs");

fn main() {
    // The key the bootloader checks a marked update with before the swap (boards/update-key.rs); test builds ask for the test key (feature test-update-key).
    write_update_key(true, std::env::var_os("CARGO_FEATURE_TEST_UPDATE_KEY").is_some());
    println!("cargo:rerun-if-changed=memory.x");
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
    }
}
