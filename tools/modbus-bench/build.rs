//! Links Debian's libmodbus (`libmodbus-dev`) on Linux.
fn main() {
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("linux") {
        println!("cargo:rustc-link-lib=modbus");
    }
}
