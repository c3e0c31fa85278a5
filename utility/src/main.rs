//! `remodaq-utility`: the RemoDAQ-8300 Utility window.
//!
//! `remodaq-utility [--search-at ADDR:PORT]... [--timeout S] [--poll-all-ms MS] [--select ADDR:PORT]`:
//! by default a search goes to the broadcast address on every interface; `--search-at` sends it
//! to modules' own discovery addresses instead (simulated modules on this PC); `--select` opens
//! the panel of the module whose Modbus address it names once the first search finds it.

#![cfg_attr(windows, windows_subsystem = "windows")]

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use eframe::egui::Ui;
use remodaq_utility::app::{model_of, module_label};
use remodaq_utility::{fonts, Options, Utility};

/// The window; with `REMODAQ_UTILITY_FOUND=FILE` (a test's aid: scripts/utility-wine reads it)
/// it also writes what it shows to FILE after each frame that changed it, else at most once a
/// second: `frames N modules M read R`, then `module LABEL model MODEL|unread` per module in
/// its tree.
struct Window {
    utility: Utility,
    found: Option<PathBuf>,
    /// The modules' lines last written, and when.
    written: Option<(String, Instant)>,
}

impl Window {
    fn write_found(&mut self) {
        let Some(path) = &self.found else { return };
        let u = &self.utility;
        let modules = u.modules();
        let reading = |mac| u.latest(mac).map(model_of);
        let mut lines = String::new();
        for m in modules {
            let model = reading(m.mac).map_or("unread".to_string(), |model| format!("model {model:04x}"));
            lines += &format!("module {} {model}\n", module_label(m));
        }
        if self.written.as_ref().is_some_and(|(w, t)| *w == lines && t.elapsed() < Duration::from_secs(1)) {
            return;
        }
        let read = modules.iter().filter(|m| reading(m.mac).is_some()).count();
        let text = format!("frames {} modules {} read {read}\n{lines}", u.stats.frames, modules.len());
        // A test's aid: a failure to write it changes nothing in the window.
        let _ = std::fs::write(path, text);
        self.written = Some((lines, Instant::now()));
    }
}

impl eframe::App for Window {
    fn ui(&mut self, ui: &mut Ui, frame: &mut eframe::Frame) {
        eframe::App::ui(&mut self.utility, ui, frame);
        self.write_found();
    }
}

fn options() -> Result<Options, String> {
    let mut o = Options::default();
    let mut at = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = |what: &str| args.next().ok_or_else(|| format!("{a} needs {what}"));
        match a.as_str() {
            "--search-at" => {
                let v = value("ADDR:PORT")?;
                at.push(v.parse::<SocketAddr>().map_err(|_| format!("`{v}` is not ADDR:PORT"))?);
            }
            "--timeout" => {
                let v = value("seconds")?;
                let s: f64 =
                    v.parse().ok().filter(|s: &f64| s.is_finite()).ok_or_else(|| format!("`{v}` is not seconds"))?;
                o.timeout = Duration::from_secs_f64(s.clamp(0.05, 60.0));
            }
            "--poll-all-ms" => {
                let v = value("milliseconds")?;
                let ms: u64 = v.parse().map_err(|_| format!("`{v}` is not milliseconds"))?;
                o.slow_poll = Duration::from_millis(ms.max(50));
            }
            "--select" => {
                let v = value("ADDR:PORT")?;
                o.select = Some(v.parse::<SocketAddr>().map_err(|_| format!("`{v}` is not ADDR:PORT"))?);
            }
            "--version" => return Err(format!("remodaq-utility {}", env!("CARGO_PKG_VERSION"))),
            other => {
                return Err(format!(
                "unknown argument `{other}` (--search-at ADDR:PORT, --timeout S, --poll-all-ms MS, --select ADDR:PORT)"
            ))
            }
        }
    }
    if !at.is_empty() {
        o.search_at = at;
    }
    o.stats = std::env::var_os("REMODAQ_UTILITY_STATS").map(std::path::PathBuf::from);
    Ok(o)
}

/// A panic is a defect: it is written to a log next to the temp files and shown in a message
/// box on Windows (where the program has no console), on standard error elsewhere. The last
/// resort, not the plan.
fn panic_hook() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let log = std::env::temp_dir().join("remodaq-utility-crash.log");
        let text = format!("remodaq-utility {}: {info}\n", env!("CARGO_PKG_VERSION"));
        let _ = std::fs::write(&log, &text);
        let text = format!("{text}(written to {})", log.display());
        eprintln!("{text}");
        message_box(&text);
        default(info);
    }));
}

#[cfg(windows)]
fn message_box(text: &str) {
    #[link(name = "user32")]
    extern "system" {
        fn MessageBoxW(hwnd: *mut core::ffi::c_void, text: *const u16, caption: *const u16, kind: u32) -> i32;
    }
    let wide = |s: &str| s.encode_utf16().chain(Some(0)).collect::<Vec<u16>>();
    let (text, caption) = (wide(text), wide("RemoDAQ-8300 Utility"));
    const MB_ICONERROR: u32 = 0x10;
    // SAFETY: both strings are NUL-terminated UTF-16 that live across the call; a null owner
    // window is allowed (MessageBoxW, user32, Windows API documentation).
    unsafe {
        MessageBoxW(core::ptr::null_mut(), text.as_ptr(), caption.as_ptr(), MB_ICONERROR);
    }
}

#[cfg(not(windows))]
fn message_box(_text: &str) {}

fn main() -> std::process::ExitCode {
    panic_hook();
    let options = match options() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("{e}");
            return std::process::ExitCode::from(2);
        }
    };
    let native = eframe::NativeOptions {
        viewport: eframe::egui::ViewportBuilder::default()
            .with_title("RemoDAQ-8300 Utility")
            .with_inner_size([1100.0, 720.0])
            .with_min_inner_size([640.0, 420.0]),
        renderer: eframe::Renderer::Glow,
        ..Default::default()
    };
    let found = std::env::var_os("REMODAQ_UTILITY_FOUND").map(PathBuf::from);
    let result = eframe::run_native(
        "RemoDAQ-8300 Utility",
        native,
        Box::new(move |cc| {
            fonts::install(&cc.egui_ctx);
            Ok(Box::new(Window { utility: Utility::new(&cc.egui_ctx, options)?, found, written: None }))
        }),
    );
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("remodaq-utility: {e}");
            std::process::ExitCode::from(1)
        }
    }
}
