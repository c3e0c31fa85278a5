//! The simulated module's command line (spec host-build.md).

use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;

use clap::Parser;

/// Options common to both simulated modules.
#[derive(Debug, Parser)]
#[command(
    version,
    about = "A RemoDAQ-8300 module simulated on this PC: the module's application with simulated inputs, Modbus/TCP on std sockets and settings in a flash image file."
)]
pub struct Options {
    /// Where the Modbus/TCP server listens, as ADDR:PORT, or ADDR alone for the port from the
    /// module's settings. Default: 127.0.0.1 and the port from the settings (factory 8000).
    #[arg(long, value_name = "ADDR[:PORT]", value_parser = parse_listen)]
    pub listen: Option<Listen>,

    /// The settings flash image. Settings survive a restart with the same file; a missing file
    /// is a blank flash (factory defaults). Default: `remodaq-<model>.flash` in the OS temp dir.
    #[arg(long, value_name = "FILE")]
    pub flash: Option<PathBuf>,

    /// The simulated signals at the terminals (TOML, see the README). The file is read again
    /// when it changes. Without it: 8318 inputs at 0 mV with 25 °C terminals; 8350 inputs low.
    #[arg(long, value_name = "FILE")]
    pub scenario: Option<PathBuf>,

    /// Where the discovery / configuration service (UDP) listens.
    #[arg(long, value_name = "ADDR:PORT", default_value = "0.0.0.0:8300")]
    pub discovery: SocketAddr,

    /// Make every settings-flash write and erase take this many milliseconds longer (a slow
    /// flash, to watch the module go on answering while it commits).
    #[arg(long, value_name = "MS", default_value_t = 0)]
    pub slow_flash: u64,

    /// Serve the web console and its JSON API (docs/web.md) on ADDR:PORT, e.g.
    /// `127.0.0.1:8080`. Without it there is no console.
    #[arg(long, value_name = "ADDR:PORT")]
    pub http: Option<SocketAddr>,

    /// Publish the module's points to the MQTT broker at ADDR:PORT (docs/mqtt.md; plain TCP,
    /// anonymous, the default topics): a stand-in for the module's MQTT settings, not built yet.
    #[arg(long, value_name = "ADDR:PORT")]
    pub mqtt: Option<SocketAddr>,

    /// Reset every setting (network, password, I/O) to factory defaults at start-up, as
    /// holding the USER button at power-up does on the module.
    #[arg(long)]
    pub factory_reset: bool,

    /// The module's MAC address, as six hex bytes (`02:83:18:00:00:01`), instead of the one
    /// derived from the flash image's path: a fixed identity for tests that show it (snapshots).
    /// A unicast address (bit 0 of the first byte clear).
    #[arg(long, value_name = "MAC", value_parser = parse_mac)]
    pub mac: Option<[u8; 6]>,
}

/// A `--listen` value.
#[derive(Clone, Copy, Debug)]
pub enum Listen {
    /// Address and port.
    Addr(SocketAddr),
    /// Address; the port comes from the settings.
    Ip(IpAddr),
}

fn parse_listen(s: &str) -> Result<Listen, String> {
    s.parse::<SocketAddr>()
        .map(Listen::Addr)
        .or_else(|_| s.parse::<IpAddr>().map(Listen::Ip))
        .map_err(|_| format!("`{s}` is not ADDR or ADDR:PORT"))
}

fn parse_mac(s: &str) -> Result<[u8; 6], String> {
    let bad = || format!("`{s}` is not a MAC address (six hex bytes: 02:83:18:00:00:01)");
    let parts: Vec<&str> = s.split([':', '-']).collect();
    if parts.len() != 6 {
        return Err(bad());
    }
    let mut mac = [0u8; 6];
    for (byte, part) in mac.iter_mut().zip(parts) {
        if part.len() != 2 || !part.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(bad());
        }
        *byte = u8::from_str_radix(part, 16).map_err(|_| bad())?;
    }
    if mac[0] & 1 != 0 {
        return Err(format!("`{s}` is a multicast address: a module's MAC is unicast"));
    }
    Ok(mac)
}

impl Options {
    /// The flash image path, defaulting to a file named after the program's model
    /// (`firmware-8318` -> `remodaq-8318.flash`) in the OS temp dir.
    pub fn flash_path(&self) -> PathBuf {
        self.flash.clone().unwrap_or_else(|| {
            let program = std::env::current_exe()
                .ok()
                .and_then(|p| p.file_stem().map(|s| s.to_string_lossy().trim_start_matches("firmware-").to_owned()))
                .unwrap_or_else(|| "module".into());
            std::env::temp_dir().join(format!("remodaq-{program}.flash"))
        })
    }

    /// The listen address: `--listen`, with the settings' port where it gives none; else
    /// 127.0.0.1 on the settings' port.
    pub fn listen_addr(&self, settings_port: u16) -> SocketAddr {
        match self.listen {
            Some(Listen::Addr(addr)) => addr,
            Some(Listen::Ip(ip)) => SocketAddr::new(ip, settings_port),
            None => SocketAddr::from(([127, 0, 0, 1], settings_port)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mac_is_six_hex_bytes_and_unicast() {
        assert_eq!(parse_mac("02:83:18:00:00:01"), Ok([0x02, 0x83, 0x18, 0, 0, 1]));
        assert_eq!(parse_mac("02-83-50-AB-cd-ef"), Ok([0x02, 0x83, 0x50, 0xab, 0xcd, 0xef]));
        for bad in
            ["", "02:83:18:00:00", "02:83:18:00:00:01:02", "02:83:18:00:00:1", "02:83:18:00:00:0g", "+2:83:18:00:00:01"]
        {
            assert!(parse_mac(bad).is_err(), "{bad}");
        }
        assert!(parse_mac("01:00:5e:00:00:01").is_err(), "multicast");
        let o = Options::try_parse_from(["firmware-8318", "--mac", "02:00:00:00:00:07"]).expect("parsed");
        assert_eq!(o.mac, Some([2, 0, 0, 0, 0, 7]));
        assert_eq!(Options::try_parse_from(["firmware-8318"]).expect("parsed").mac, None);
    }
}
