//! The build script of the target images (`build` in the Cargo.toml of both image crates and
//! of `tools/on-target`). Target builds: the workspace's `memory.x` (STM32F429ZI) on the linker
//! search path, and the cortex-m-rt and defmt linker scripts. Every build: the update key and the
//! firmware version of the image (boards/update-key.rs), read here, in the image crate, so that a
//! test image of another version or key rebuilds only this crate.
include!("update-key.rs");

fn main() {
    // A module's image (firmware-*) refuses to build without a key unless it asks for the test
    // key (feature test-update-key; the QEMU board's images do). The on-target test image uses
    // no key.
    let package = std::env::var("CARGO_PKG_NAME").unwrap_or_default();
    write_update_key(package.starts_with("firmware-"), std::env::var_os("CARGO_FEATURE_TEST_UPDATE_KEY").is_some());
    write_firmware_version();
    // The workspace root: the first directory up from the package that holds memory.x.
    let package = std::path::PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").unwrap_or_default());
    let root = package.ancestors().find(|dir| dir.join("memory.x").exists()).unwrap_or(&package).to_path_buf();
    println!("cargo:rerun-if-changed={}", root.join("memory.x").display());
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        // A link argument, not a link-search path: search paths of a build script reach every
        // package that depends on this one, and tools linking their own memory.x must not see it.
        println!("cargo:rustc-link-arg-bins=-L{}", root.display());
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
}
