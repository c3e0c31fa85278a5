//! The update key (boards/update-key.rs). Target builds: cortex-m-rt's linker script (which includes this crate's memory.x: the
//! build links from this directory, see boards/ld).
include!("../../update-key.rs");

fn main() {
    // The key the bootloader checks a marked update with before the swap (boards/update-key.rs): the QEMU board is a test board and trusts the repository's test key.
    write_update_key(true, true);
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=../layout.x");
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
    }
}
