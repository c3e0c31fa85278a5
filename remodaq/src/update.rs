//! `remodaq update`: the update (`remodaq_client::update`) with a progress bar, and the
//! firmware version before and after.

use std::path::Path;
use std::time::Duration;

use remodaq_client::update::{self, Progress};
use remodaq_client::Error;

/// `remodaq update MODULE IMAGE`.
pub async fn update(
    module: &str,
    mac: Option<remodaq_client::lan::Mac>,
    image: &Path,
    password: &str,
    port: u16,
    timeout: Duration,
    json: bool,
) -> Result<(), Error> {
    let bar = if json { indicatif::ProgressBar::hidden() } else { indicatif::ProgressBar::new(0) };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {bytes}/{total_bytes} {bytes_per_sec} {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let done = update::update(module, mac, image, password, port, timeout, |p| match p {
        Progress::Sent(sent, total) => {
            bar.set_length(total);
            bar.set_position(sent);
        }
        Progress::Verifying => bar.set_message("verifying"),
        Progress::Restarting(addr, version) => {
            bar.finish_and_clear();
            if !json {
                println!("{addr}: version {version:04X} verified and marked; the module restarts into it");
            }
        }
    })
    .await;
    bar.finish_and_clear();
    let done = done?;
    let (addr, before, after) = (done.module, done.before, done.after);
    if json {
        let out = serde_json::json!({ "module": addr.to_string(), "before": format!("{before:04X}"), "after": format!("{after:04X}") });
        println!("{out}");
    } else {
        println!("{addr}: firmware {before:04X} -> {after:04X}");
    }
    Ok(())
}
