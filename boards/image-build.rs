//! The build script of both image crates (`build` in their Cargo.toml). Target builds: the
//! workspace's `memory.x` (STM32F429ZI) on the linker search path, and the cortex-m-rt and
//! defmt linker scripts.
fn main() {
    println!("cargo:rerun-if-changed=../memory.x");
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        // A link argument, not a link-search path: search paths of a build script reach every
        // package that depends on this one, and tools linking their own memory.x must not see it.
        println!("cargo:rustc-link-arg-bins=-L{}", root.display());
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
}
