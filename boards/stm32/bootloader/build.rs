//! The update key (boards/update-key.rs). Target builds: cortex-m-rt's linker script (which includes this crate's memory.x: the
//! build links from this directory, see boards/ld).
include!("../../update-key.rs");

fn main() {
    // The key the bootloader checks a marked update with before the swap (boards/update-key.rs); test builds ask for the test key (feature test-update-key).
    write_update_key(true, std::env::var_os("CARGO_FEATURE_TEST_UPDATE_KEY").is_some());
    println!("cargo:rerun-if-changed=memory.x");
    write_layout();
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
    }
}

/// The flash layout as the linker scripts give it, for main.rs's compile-time checks (stm32
/// review N2): the application's memory.x (the workspace's: its FLASH region is ACTIVE, and the
/// `__bootloader_*` symbols it links embassy-boot's partitions with) and this bootloader's own.
/// Written to `OUT_DIR/layout.rs` as `APP_*` and `BOOT_*` constants.
fn write_layout() {
    let app_path = "../../../memory.x";
    println!("cargo:rerun-if-changed={app_path}");
    let app = std::fs::read_to_string(app_path).unwrap_or_else(|e| panic!("{app_path}: {e}"));
    let boot = std::fs::read_to_string("memory.x").unwrap_or_else(|e| panic!("memory.x: {e}"));
    let (origin, length) = region(&app, "FLASH");
    let mut out = format!("const APP_FLASH_ORIGIN: u32 = {origin:#x};\nconst APP_FLASH_LENGTH: u32 = {length:#x};\n");
    for (prefix, text) in [("APP", &app), ("BOOT", &boot)] {
        for name in ["state_start", "state_end", "dfu_start", "dfu_end"] {
            let value = symbol(text, &format!("__bootloader_{name}"));
            out.push_str(&format!("const {prefix}_{}: u32 = {value:#x};\n", name.to_uppercase()));
        }
    }
    for name in ["active_start", "active_end"] {
        let value = symbol(&boot, &format!("__bootloader_{name}"));
        out.push_str(&format!("const BOOT_{}: u32 = {value:#x};\n", name.to_uppercase()));
    }
    let path = std::path::PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR")).join("layout.rs");
    std::fs::write(&path, out).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

/// A number of a linker script: hex (`0x...`), or decimal with an optional `K` or `M`.
fn number(text: &str) -> u32 {
    let text = text.trim();
    if let Some(hex) = text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        return u32::from_str_radix(&hex.replace('_', ""), 16).unwrap_or_else(|e| panic!("{text}: {e}"));
    }
    let (digits, unit) = match text.as_bytes().last() {
        Some(b'K') => (&text[..text.len() - 1], 1024),
        Some(b'M') => (&text[..text.len() - 1], 1024 * 1024),
        _ => (text, 1),
    };
    digits.parse::<u32>().unwrap_or_else(|e| panic!("{text}: {e}")) * unit
}

/// `NAME : ORIGIN = a, LENGTH = b` of a MEMORY block.
fn region(script: &str, name: &str) -> (u32, u32) {
    let line = script
        .lines()
        .map(str::trim)
        .find(|l| l.split(':').next().map(str::trim) == Some(name) && l.contains("ORIGIN"))
        .unwrap_or_else(|| panic!("no region {name} in memory.x"));
    let field = |key: &str| {
        let rest = line.split(key).nth(1).unwrap_or_else(|| panic!("{name}: no {key}"));
        number(rest.trim_start().trim_start_matches('=').split(',').next().unwrap_or(""))
    };
    (field("ORIGIN"), field("LENGTH"))
}

/// `NAME = value;` of a linker script.
fn symbol(script: &str, name: &str) -> u32 {
    let line = script
        .lines()
        .map(str::trim)
        .find(|l| l.split('=').next().map(str::trim) == Some(name))
        .unwrap_or_else(|| panic!("no {name} in a memory.x"));
    number(line.split('=').nth(1).unwrap_or("").trim_end_matches(';'))
}
