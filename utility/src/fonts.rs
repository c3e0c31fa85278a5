//! The CJK font the Chinese texts need (egui's own fonts have no Han characters): the system's,
//! found by path, as a fallback after egui's fonts.
//!
//! - Windows: Microsoft YaHei (`%WINDIR%\Fonts\msyh.ttc`), else SimSun; under Wine the Debian
//!   font through drive Z:.
//! - Linux: WenQuanYi Micro Hei (Debian `fonts-wqy-microhei`), Noto Sans CJK, Droid Sans
//!   Fallback.
//! - macOS: PingFang, Hiragino Sans GB, Arial Unicode.
//!
//! `REMODAQ_CJK_FONT` names another file. Without any, Chinese shows as boxes and the English
//! texts are unaffected.

use std::path::PathBuf;

/// Where to look, in order.
pub fn candidates() -> Vec<PathBuf> {
    let mut paths = Vec::new();
    if let Some(p) = std::env::var_os("REMODAQ_CJK_FONT") {
        paths.push(PathBuf::from(p));
    }
    if cfg!(windows) {
        let windir = std::env::var_os("WINDIR").map_or_else(|| PathBuf::from(r"C:\Windows"), PathBuf::from);
        for f in ["msyh.ttc", "msyh.ttf", "simsun.ttc"] {
            paths.push(windir.join("Fonts").join(f));
        }
        paths.push(PathBuf::from(r"Z:\usr\share\fonts\truetype\wqy\wqy-microhei.ttc"));
    } else if cfg!(target_os = "macos") {
        for f in [
            "/System/Library/Fonts/PingFang.ttc",
            "/System/Library/Fonts/Hiragino Sans GB.ttc",
            "/Library/Fonts/Arial Unicode.ttf",
        ] {
            paths.push(PathBuf::from(f));
        }
    } else {
        for f in [
            "/usr/share/fonts/truetype/wqy/wqy-microhei.ttc",
            "/usr/share/fonts/opentype/noto/NotoSansCJK-Regular.ttc",
            "/usr/share/fonts/noto-cjk/NotoSansCJK-Regular.ttc",
            "/usr/share/fonts/truetype/droid/DroidSansFallbackFull.ttf",
        ] {
            paths.push(PathBuf::from(f));
        }
    }
    paths
}

/// Adds the first CJK font found as the last fallback of both families; says which (`None`:
/// none found).
pub fn install(ctx: &eframe::egui::Context) -> Option<PathBuf> {
    use eframe::egui::{FontData, FontFamily};
    use eframe::epaint::text::{FontInsert, FontPriority, InsertFontFamily};
    let (path, bytes) = candidates().into_iter().find_map(|p| std::fs::read(&p).ok().map(|b| (p, b)))?;
    let families = [FontFamily::Proportional, FontFamily::Monospace]
        .into_iter()
        .map(|family| InsertFontFamily { family, priority: FontPriority::Lowest })
        .collect();
    ctx.add_font(FontInsert { name: "cjk".into(), data: FontData::from_owned(bytes), families });
    log::info!("CJK font: {}", path.display());
    Some(path)
}
