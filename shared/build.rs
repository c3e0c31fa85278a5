//! Compresses the web console's pages (`web/`) with gzip at build time into `OUT_DIR`, for the
//! service to serve from flash as they are (issue #25: no CDN, no download, works offline;
//! docs/web.md). The gzip header carries no time, so a build is reproducible.

use std::io::Write;

/// The pages' files, as `shared::web::service` serves them.
const FILES: [&str; 4] = ["index.html", "app.js", "auth.js", "style.css"];

fn main() {
    let out = std::path::PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    for name in FILES {
        let path = format!("web/{name}");
        println!("cargo:rerun-if-changed={path}");
        let text = std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
        let mut gz = flate2::GzBuilder::new().mtime(0).write(Vec::new(), flate2::Compression::best());
        gz.write_all(&text).expect("gzip into memory");
        let gz = gz.finish().expect("gzip into memory");
        std::fs::write(out.join(format!("{name}.gz")), gz).unwrap_or_else(|e| panic!("{name}.gz: {e}"));
    }
}
