//! Compresses the web console's pages (`web/`) with gzip at build time into `OUT_DIR`, for the
//! service to serve from flash as they are (issue #25: no CDN, no download, works offline;
//! docs/web.md). The gzip header carries no time, so a build is reproducible. The scripts and
//! the style sheet go in without their comment lines and indentation (3 KB less of flash;
//! docs/web.md, "Budgets").

use std::io::Write;

/// The pages' files, as `shared::web::service` serves them.
const FILES: [&str; 4] = ["index.html", "app.js", "auth.js", "style.css"];

fn main() {
    let out = std::path::PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    for name in FILES {
        let path = format!("web/{name}");
        println!("cargo:rerun-if-changed={path}");
        let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
        let text = if name.ends_with(".html") { text } else { lean(&text) };
        let mut gz = flate2::GzBuilder::new().mtime(0).write(Vec::new(), flate2::Compression::best());
        gz.write_all(text.as_bytes()).expect("gzip into memory");
        let gz = gz.finish().expect("gzip into memory");
        std::fs::write(out.join(format!("{name}.gz")), gz).unwrap_or_else(|e| panic!("{name}.gz: {e}"));
    }
}

/// `text` (a script or a style sheet) without its indentation, blank lines and whole-line `//`
/// comments. Each line stays a line, so JavaScript reads the same (no line of the pages
/// continues a string or a template onto the next: tools/browser runs them as served).
fn lean(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for line in text.lines().map(str::trim).filter(|l| !l.is_empty() && !l.starts_with("//")) {
        out.push_str(line);
        out.push('\n');
    }
    out
}
