//! Target builds: the workspace's `memory.x` (STM32F429ZI; the QEMU board's linker wrapper puts
//! its own first) and the cortex-m-rt and defmt linker scripts.
fn main() {
    println!("cargo:rerun-if-changed=../../memory.x");
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        println!("cargo:rustc-link-arg-bins=-L{}", root.display());
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
}
