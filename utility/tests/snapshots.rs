//! Snapshot images of the utility's main views (issue #22), rendered with wgpu (Mesa's software
//! Vulkan on Linux) and compared with the committed images in `tests/snapshots/`. Nothing in
//! them changes from run to run: the simulated modules have fixed MACs (`--mac`) and ports,
//! their inputs come from scenario files, the trend's points are timed by a clock the test
//! holds, and the one live field shown, a module's uptime in the Network Settings tab, is
//! painted over. So the tolerance is only what font rendering may change on another machine
//! ([`MAX_FAILED_PIXELS`]): a value, a lamp or the trend's curve that moves fails.
//! `UPDATE_SNAPSHOTS=1` writes new ones; look at them before committing.

mod support;

use std::time::Duration;

use eframe::egui::{self, Color32};
use egui_kittest::{SnapshotOptions, SnapshotResults};
use support::*;

/// Pixels that may differ (beyond egui_kittest's per-pixel threshold): anti-aliasing of the
/// text on another machine's rasterizer (on this one, two runs give the same pictures to the
/// pixel). A glyph is some 30 pixels (the seven values of the 8318 panel about 1,400, the
/// trend's curve about 2,000): one changed digit may pass, a wrong value, lamp or curve fails.
const MAX_FAILED_PIXELS: usize = 50;

/// Compares what the utility shows with `tests/snapshots/NAME.png`, the uptime painted over.
fn snapshot(gui: &mut Gui, results: &mut SnapshotResults, name: &str) {
    let mut image = gui.harness.render().expect("rendered");
    // "MAC … · firmware A100 · up 12 s": the number and its unit are covered, from where the
    // text before them ends (laid out in the label's font) to where six digits would end.
    if let Some((text, rect)) = gui.text_starting("MAC ") {
        let prefix =
            text.trim_end_matches(|c: char| !c.is_ascii_digit()).trim_end_matches(|c: char| c.is_ascii_digit());
        assert!(prefix.len() < text.len(), "no uptime at the end of {text:?}");
        let ctx = gui.harness.ctx.clone();
        let font = egui::TextStyle::Body.resolve(&ctx.global_style());
        let width = |s: &str| ctx.fonts_mut(|f| f.layout_no_wrap(s.to_string(), font.clone(), Color32::WHITE).size().x);
        let ppp = ctx.pixels_per_point();
        let (from, to) = (rect.left() + width(prefix) - 1.0, rect.left() + width(&format!("{prefix}000000 s")) + 1.0);
        let (x0, x1) = ((from * ppp).floor() as u32, ((to * ppp).ceil() as u32).min(image.width()));
        let (y0, y1) = ((rect.top() * ppp).floor() as u32, ((rect.bottom() * ppp).ceil() as u32).min(image.height()));
        for y in y0..y1 {
            for x in x0..x1 {
                image.get_pixel_mut(x, y).0 = [0x40, 0x40, 0x40, 0xff];
            }
        }
    }
    let options = SnapshotOptions::new().max_failed_pixels(MAX_FAILED_PIXELS);
    results.add(egui_kittest::try_image_snapshot_options(&image, name, &options));
}

/// The 8318's scenario with CH3 at `ch3` mV (type K with 24.5 °C terminals: 5-15 mV is about
/// 150-390 °C).
fn scenario_8318(ch3: f64) -> String {
    format!(
        "cjc_celsius = 24.5\n[ch0]\nopen = true\n[ch1]\nmillivolts = 40.0\n[ch2]\nmillivolts = 1.0\n[ch3]\nmillivolts = {ch3:.3}\n"
    )
}

/// When the trend's wave starts, s on the utility's clock, and when the trend is paused.
const WAVE: u64 = 30;
const PAUSE: u64 = 70;

/// CH3's input at `t` s: steady, then a wave of 20 s.
fn ch3_mv(t: u64) -> f64 {
    if t < WAVE {
        12.2
    } else {
        10.0 + 5.0 * ((t - WAVE) as f64 * std::f64::consts::TAU / 20.0).sin()
    }
}

/// What a type K channel reads for `mv` at 24.5 °C terminals (NIST ITS-90: the emf of the
/// cold junction added, then the table inverted).
fn type_k_at_24_5(mv: f64) -> f64 {
    nist_k_temperature(mv + nist_k_emf(24.5))
}

#[test]
fn snapshots_of_the_main_views() {
    let s8318 = Scenario::new("snap-8318", &scenario_8318(12.2));
    let s8350 = Scenario::new("snap-8350", "[di1]\nlevel = true\n[di4]\nlevel = true\n");
    // Fixed ports (the tree shows them), below Linux's ephemeral range (32768-) and above the
    // QEMU tests' (20000-31999); fixed MACs (the heading shows them).
    let m8318 =
        Sim::start_at("8318", "snap", 32318, 32319, &["--scenario", s8318.path(), "--mac", "02:83:18:00:00:01"]);
    let m8350 =
        Sim::start_at("8350", "snap", 32350, 32351, &["--scenario", s8350.path(), "--mac", "02:83:50:00:00:01"]);
    let clock = Clock::manual();
    let mut gui =
        Gui::with(vec![m8318.discovery(), m8350.discovery()], egui::vec2(1100.0, 760.0), TIMEOUT, clock.clone());
    let mut results = SnapshotResults::new();

    // The main window: the tree and a module's network settings.
    gui.select_module("RemoDAQ-8318", m8318.port());
    gui.frames(5);
    assert!(gui.has_part("MAC 02:83:18:00:00:01 · firmware A100 · up "), "the MAC line");
    snapshot(&mut gui, &mut results, "main_window");

    // The 8318 panel, type K, live values.
    gui.click("RemoDAQ-8318");
    gui.choose("Input range", "0F thermocouple K");
    gui.click("Setting");
    gui.wait("type K values", |g| g.has("CH0 open") && g.has_value("CH1 ", "°C"));
    gui.frames_for(Duration::from_millis(500));
    snapshot(&mut gui, &mut results, "panel_8318");

    // The 8350 panel.
    let node = format!("RemoDAQ-8350 (127.0.0.1:{})", m8350.port());
    gui.click(&node);
    gui.click("RemoDAQ-8350");
    gui.wait("the 8350 panel", |g| g.has("● DI1 ON"));
    gui.frames_for(Duration::from_millis(500));
    snapshot(&mut gui, &mut results, "panel_8350");

    // A trend of more than 30 s. The utility's clock stood at 0 so far; the test moves it a
    // second at a time, writes that second's input to the scenario (from WAVE on: steady,
    // then a wave), and waits for a reading of CH3 timed then with its value (spec: NIST type
    // K). So the curve goes through known values at whole seconds, and the trend, paused at
    // PAUSE, shows the minute before it the same way in every run.
    gui.click(&format!("RemoDAQ-8318 (127.0.0.1:{})", m8318.port()));
    gui.click("Trends");
    let name = &format!("RemoDAQ-8318 (127.0.0.1:{}) CH3 (°C)", m8318.port());
    gui.click(name);
    let point_at = |gui: &mut Gui, t: u64, mv: f64| {
        let want = type_k_at_24_5(mv);
        gui.wait(&format!("CH3's point at {t} s, {want:.2} °C"), |g| {
            g.app().trend.series[name].back().is_some_and(|p| p[0] == t as f64 && (p[1] - want).abs() <= 0.1)
        });
    };
    for t in 1..=PAUSE {
        clock.set(Duration::from_secs(t));
        if t >= WAVE {
            s8318.write(&scenario_8318(ch3_mv(t)));
        }
        point_at(&mut gui, t, ch3_mv(t));
    }
    gui.frames(3);
    gui.click("Pause");
    // Readings go on after the pause, timed after it: the paused trend does not draw them.
    clock.set(Duration::from_secs(PAUSE + 1));
    gui.frames(3);
    let points = &gui.app().trend.series[name];
    let span = points.back().map_or(0.0, |p| p[0]) - points.front().map_or(0.0, |p| p[0]);
    assert!(span >= 30.0, "the trend holds {span:.1} s");
    // The held clock gives all the readings between two of its moves one time, which a
    // running clock never does (egui_plot draws points less than a pixel apart as a band):
    // of each time, the last point is kept, as the CSV export keeps one row per time.
    for series in gui.app_mut().trend.series.values_mut() {
        let mut kept: std::collections::VecDeque<[f64; 2]> = std::collections::VecDeque::new();
        for p in series.drain(..) {
            match kept.back_mut() {
                Some(last) if last[0] == p[0] => *last = p,
                _ => kept.push_back(p),
            }
        }
        *series = kept;
    }
    gui.frames(2);
    snapshot(&mut gui, &mut results, "trend");

    // What the trend shows, exported: a time column and the picked series, one row a second
    // over the minute in view, each the value of that second's input.
    let csv = std::env::temp_dir().join("remodaq-utility-snapshots-trend.csv");
    gui.set_text("CSV file", csv.to_str().expect("utf-8"));
    gui.click("Export CSV");
    gui.wait("written", |g| g.has_part("Trend written to"));
    let text = std::fs::read_to_string(&csv).expect("the CSV file");
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some(format!("time_s,\"{name}\"").as_str()));
    let rows: Vec<(f64, f64)> = lines
        .map(|l| {
            let (t, v) = l.split_once(',').unwrap_or_else(|| panic!("a row: {l:?}"));
            (t.parse().expect("a time"), v.parse().expect("a value"))
        })
        .collect();
    let times: Vec<f64> = rows.iter().map(|r| r.0).collect();
    let expected: Vec<f64> = (PAUSE - 60..=PAUSE).map(|t| t as f64).collect();
    assert_eq!(times, expected, "one row a second over the minute in view");
    for (t, v) in rows {
        let want = type_k_at_24_5(ch3_mv(t as u64));
        assert!((v - want).abs() <= 0.1, "at {t} s: {v} °C, NIST {want:.3} °C");
    }

    // The main window in Chinese (the CJK font of the system).
    gui.click("Network Settings");
    gui.click("中文");
    gui.frames(5);
    snapshot(&mut gui, &mut results, "main_window_zh");
    results.unwrap();
}
