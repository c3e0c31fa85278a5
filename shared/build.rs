//! The public key firmware images are verified with (docs/update.md): the 64 hex digits of the
//! file named by `REMODAQ_UPDATE_KEY`, else the repository's test key
//! (`keys/test-update.key.pub`), as `UPDATE_KEY` in `$OUT_DIR/update_key.rs`.
use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-env-changed=REMODAQ_UPDATE_KEY");
    let manifest = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").unwrap_or_default());
    let path = match std::env::var_os("REMODAQ_UPDATE_KEY") {
        Some(path) => PathBuf::from(path),
        None => manifest.join("../keys/test-update.key.pub"),
    };
    println!("cargo:rerun-if-changed={}", path.display());
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("the update key {}: {e} (REMODAQ_UPDATE_KEY names another)", path.display()));
    let text = text.trim();
    let bytes: Vec<u8> =
        (0..text.len() / 2).filter_map(|i| u8::from_str_radix(text.get(2 * i..2 * i + 2)?, 16).ok()).collect();
    assert!(text.len() == 64 && bytes.len() == 32, "the update key {}: not 64 hex digits", path.display());
    let out = PathBuf::from(std::env::var_os("OUT_DIR").unwrap_or_default()).join("update_key.rs");
    let code = format!(
        "/// The public key firmware images must be signed for (from `{}`).\npub const UPDATE_KEY: [u8; 32] = {bytes:?};\n",
        path.display()
    );
    std::fs::write(&out, code).unwrap_or_else(|e| panic!("{}: {e}", out.display()));
}
