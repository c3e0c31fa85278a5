//! Builds libmodbus 3.1.6 from its C sources (`LIBMODBUS_SRC`, the `src` folder of the sources;
//! `tools/modbus-bench/run` sets it) as one translation unit at -O3, the C counterpart of fat
//! LTO with one codegen unit, with `libmodbus-bench.c`'s memory backend. Linux only.
use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-changed=libmodbus-bench.c");
    println!("cargo:rerun-if-env-changed=LIBMODBUS_SRC");
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("linux") {
        return;
    }
    let Some(src) = std::env::var_os("LIBMODBUS_SRC").map(PathBuf::from) else {
        println!("cargo:warning=LIBMODBUS_SRC is not set: run tools/modbus-bench/run");
        std::process::exit(1);
    };
    let out = PathBuf::from(std::env::var_os("OUT_DIR").unwrap_or_default());
    // What libmodbus's configure would write on this platform, for the parts the TCP server uses.
    let config = "#define HAVE_ACCEPT4 1\n#define HAVE_ERRNO_H 1\n#define HAVE_NETINET_IN_H 1\n";
    let version = "#define LIBMODBUS_VERSION_MAJOR (3)\n#define LIBMODBUS_VERSION_MINOR (1)\n\
                   #define LIBMODBUS_VERSION_MICRO (6)\n#define LIBMODBUS_VERSION 3.1.6\n\
                   #define LIBMODBUS_VERSION_STRING \"3.1.6\"\n";
    for (name, text) in [("config.h", config), ("modbus-version.h", version)] {
        if let Err(e) = std::fs::write(out.join(name), text) {
            println!("cargo:warning=cannot write {name}: {e}");
            std::process::exit(1);
        }
    }
    cc::Build::new()
        .file("libmodbus-bench.c")
        .include(&out)
        .include(&src)
        .define("HAVE_CONFIG_H", None)
        .opt_level(3)
        // As the Rust side (the profile's debug info does not keep frame pointers there).
        .force_frame_pointer(false)
        .warnings(false)
        .compile("modbus_bench_c");
}
