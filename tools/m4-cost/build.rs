//! Target builds: the cortex-m-rt linker script. The memory layout is the workspace's
//! `memory.x` (STM32F429), which QEMU's netduinoplus2 (STM32F405) maps the same way.
fn main() {
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
    }
}
