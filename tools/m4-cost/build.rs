//! Target builds: the cortex-m-rt linker script, with this crate's memory.x (the build links
//! from this directory through boards/ld, see `run`): the probe boots from the flash's start.
fn main() {
    println!("cargo:rerun-if-changed=memory.x");
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
    }
}
