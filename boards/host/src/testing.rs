//! For end-to-end tests: start a simulated module as a child process and find its port.

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

/// A running simulated module; killed when dropped.
pub struct SimModule {
    child: Child,
    /// Where its Modbus/TCP server listens.
    pub addr: SocketAddr,
}

impl SimModule {
    /// Starts `binary` on an ephemeral loopback port with the flash image `flash`, and waits
    /// (at most 20 s) for its "listening on" log line.
    pub fn start(binary: &str, flash: &Path) -> Self {
        Self::start_with(binary, flash, &[])
    }

    /// As [`Self::start`], with more command-line arguments (e.g. `--scenario FILE`).
    pub fn start_with(binary: &str, flash: &Path, args: &[&str]) -> Self {
        let mut child = Command::new(binary)
            .args(["--listen", "127.0.0.1:0", "--flash"])
            .arg(flash)
            .args(args)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start the simulated module");
        let stderr = child.stderr.take().expect("stderr");
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                if let Some(addr) = line.split("modbus: listening on ").nth(1) {
                    let _ = tx.send(addr.trim().to_string());
                }
                eprintln!("[module] {line}");
            }
        });
        let addr = match rx.recv_timeout(Duration::from_secs(20)) {
            Ok(addr) => addr.parse().expect("listen address"),
            Err(_) => {
                let _ = child.kill();
                panic!("the simulated module did not report its address within 20 s");
            }
        };
        Self { child, addr }
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
