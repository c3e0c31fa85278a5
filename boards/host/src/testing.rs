//! For end-to-end tests: start a simulated module as a child process and find its addresses.

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{self, Receiver};
use std::time::Duration;

/// A running simulated module; killed when dropped.
pub struct SimModule {
    child: Child,
    lines: Receiver<(&'static str, SocketAddr)>,
    /// Where its Modbus/TCP server listens.
    pub addr: SocketAddr,
    /// Where its discovery service listens (UDP).
    pub discovery: SocketAddr,
}

impl SimModule {
    /// Starts `binary` on ephemeral loopback ports (Modbus and discovery) with the flash image
    /// `flash`, and waits (at most 20 s) for its "listening on" log lines.
    pub fn start(binary: &str, flash: &Path) -> Self {
        Self::start_with(binary, flash, &["--listen", "127.0.0.1:0"])
    }

    /// Starts `binary` with the flash image, an ephemeral loopback discovery port and `args`
    /// (which should say where Modbus listens, e.g. `--listen 127.0.0.1:0`).
    pub fn start_with(binary: &str, flash: &Path, args: &[&str]) -> Self {
        let mut child = Command::new(binary)
            .args(["--discovery", "127.0.0.1:0", "--flash"])
            .arg(flash)
            .args(args)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start the simulated module");
        let stderr = child.stderr.take().expect("stderr");
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                for what in ["modbus", "discovery"] {
                    if let Some(addr) = line.split(&format!("{what}: listening on ")).nth(1) {
                        if let Ok(addr) = addr.trim().parse() {
                            let _ = tx.send((what, addr));
                        }
                    }
                }
                eprintln!("[module] {line}");
            }
        });
        let mut module = Self { child, lines, addr: ([0, 0, 0, 0], 0).into(), discovery: ([0, 0, 0, 0], 0).into() };
        module.wait_listening();
        module
    }

    /// Waits (at most 20 s) for the module to report both addresses again (after a start or
    /// a restart) and records them.
    pub fn wait_listening(&mut self) {
        let (mut modbus, mut discovery) = (None, None);
        while modbus.is_none() || discovery.is_none() {
            match self.lines.recv_timeout(Duration::from_secs(20)) {
                Ok(("modbus", addr)) => modbus = Some(addr),
                Ok((_, addr)) => discovery = Some(addr),
                Err(_) => {
                    let _ = self.child.kill();
                    panic!("the simulated module did not report its addresses within 20 s");
                }
            }
        }
        self.addr = modbus.unwrap_or(self.addr);
        self.discovery = discovery.unwrap_or(self.discovery);
    }

    /// Kills the module (a power cut, as far as the flash image is concerned).
    pub fn kill(mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for SimModule {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
