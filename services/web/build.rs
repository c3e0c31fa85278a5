//! Compresses the web console's pages (`web/`) with gzip at build time into `OUT_DIR`, for the
//! service to serve from flash as they are (issue #25: no CDN, no download, works offline;
//! docs/web.md), by Zopfli (a smaller gzip stream than zlib's best, as any browser reads it).
//! The gzip header carries no time, so a build is reproducible. The scripts and
//! the style sheet go in without their comment lines and indentation (3 KB less of flash;
//! docs/web.md, "Budgets").

/// The pages' files, as `remodaq_web::service` serves them.
const FILES: [&str; 4] = ["index.html", "app.js", "auth.js", "style.css"];

fn main() {
    let out = std::path::PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    for name in FILES {
        let path = format!("web/{name}");
        println!("cargo:rerun-if-changed={path}");
        let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
        let text = match name.rsplit_once('.').map(|(_, kind)| kind) {
            Some("js") => lean(&text, &path, true),
            Some("css") => lean(&text, &path, false),
            _ => text,
        };
        let mut gz = Vec::new();
        zopfli::compress(zopfli::Options::default(), zopfli::Format::Gzip, text.as_bytes(), &mut gz)
            .expect("gzip into memory");
        std::fs::write(out.join(format!("{name}.gz")), gz).unwrap_or_else(|e| panic!("{name}.gz: {e}"));
    }
}

/// `text` (a script, or a style sheet: `script` false) without its indentation and blank lines,
/// and a script without its whole-line `//` comments. Each line stays a line, so a script reads
/// the same, as long as no string, template or comment spans lines: the build stops on a
/// backtick, a `/*` or a line ending in `\` in a script (tools/browser runs the pages as served).
fn lean(text: &str, path: &str, script: bool) -> String {
    let mut out = String::with_capacity(text.len());
    for line in text.lines().map(str::trim) {
        let comment = script && line.starts_with("//");
        if script && !comment && (line.contains('`') || line.contains("/*") || line.ends_with('\\')) {
            panic!(
                "{path}: a line that may go on to the next (keep strings, templates and comments on one line): {line}"
            );
        }
        if line.is_empty() || comment {
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}
