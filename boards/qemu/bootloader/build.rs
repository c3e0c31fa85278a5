//! Target builds: cortex-m-rt's linker script (which includes this crate's memory.x: the
//! build links from this directory, see boards/ld).
fn main() {
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=../layout.x");
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
    }
}
