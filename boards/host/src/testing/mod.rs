//! For end-to-end tests: start a simulated module as a child process and find its addresses.
//!
//! The programs under test are this build's by default. Two variables run the same tests on
//! other builds: `REMODAQ_E2E_BIN_DIR` (a directory holding `remodaq`, `firmware-8318` and
//! `firmware-8350`, e.g. the Windows build `target/x86_64-pc-windows-gnu/debug`) and
//! `REMODAQ_E2E_RUNNER` (a program that runs them, e.g. `wine`).

pub mod web;

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{self, Receiver};
use std::time::Duration;

/// The program `name` (`remodaq`, `firmware-8318`, ...): in `REMODAQ_E2E_BIN_DIR` if set
/// (with `.exe` where that exists), else `default`.
pub fn program(name: &str, default: &Path) -> PathBuf {
    match std::env::var_os("REMODAQ_E2E_BIN_DIR") {
        Some(dir) => {
            let dir = PathBuf::from(dir);
            let exe = dir.join(format!("{name}.exe"));
            if exe.exists() {
                exe
            } else {
                dir.join(name)
            }
        }
        None => default.to_path_buf(),
    }
}

/// A command running `program`, through `REMODAQ_E2E_RUNNER` if set.
pub fn command(program: &Path) -> Command {
    match std::env::var_os("REMODAQ_E2E_RUNNER").filter(|r| !r.is_empty()) {
        Some(runner) => {
            let mut c = Command::new(runner);
            c.arg(program);
            c
        }
        None => Command::new(program),
    }
}

/// A fresh path `name` in a directory of this test process (`tag` names the test file), for a
/// flash image: an earlier file of that name is removed.
pub fn temp(tag: &str, name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("remodaq-{tag}-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join(name);
    let _ = std::fs::remove_file(&path);
    path
}

/// A running simulated module; killed when dropped.
pub struct SimModule {
    child: Child,
    lines: Receiver<(&'static str, SocketAddr)>,
    /// Where its Modbus/TCP server listens.
    pub addr: SocketAddr,
    /// Where its discovery service listens (UDP).
    pub discovery: SocketAddr,
    /// Where its web console listens, when started with `--http`.
    pub web: Option<SocketAddr>,
}

impl SimModule {
    /// Starts `binary` on ephemeral loopback ports (Modbus and discovery) with the flash image
    /// `flash`, and waits (at most 60 s) for its "listening on" log lines.
    pub fn start(binary: &str, flash: &Path) -> Self {
        Self::start_with(binary, flash, &["--listen", "127.0.0.1:0"])
    }

    /// Starts `binary` with the flash image, an ephemeral loopback discovery port (unless
    /// `args` name one with `--discovery`) and `args` (which should say where Modbus listens,
    /// e.g. `--listen 127.0.0.1:0`).
    pub fn start_with(binary: &str, flash: &Path, args: &[&str]) -> Self {
        let discovery: &[&str] = if args.contains(&"--discovery") { &[] } else { &["--discovery", "127.0.0.1:0"] };
        let mut child = command(Path::new(binary))
            .args(discovery)
            .arg("--flash")
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
                for what in ["modbus", "discovery", "web"] {
                    if let Some(addr) = line.split(&format!("{what}: listening on ")).nth(1) {
                        if let Ok(addr) = addr.trim().parse() {
                            let _ = tx.send((what, addr));
                        }
                    }
                }
                eprintln!("[module] {line}");
            }
        });
        let mut module =
            Self { child, lines, addr: ([0, 0, 0, 0], 0).into(), discovery: ([0, 0, 0, 0], 0).into(), web: None };
        module.wait_listening();
        if args.contains(&"--http") && module.web.is_none() {
            match module.lines.recv_timeout(Duration::from_secs(60)) {
                Ok(("web", addr)) => module.web = Some(addr),
                _ => panic!("the simulated module did not report its web address"),
            }
        }
        module
    }

    /// Waits (at most 60 s) for the module to report both addresses again (after a start or
    /// a restart) and records them.
    pub fn wait_listening(&mut self) {
        let (mut modbus, mut discovery) = (None, None);
        while modbus.is_none() || discovery.is_none() {
            match self.lines.recv_timeout(Duration::from_secs(60)) {
                Ok(("modbus", addr)) => modbus = Some(addr),
                Ok(("discovery", addr)) => discovery = Some(addr),
                Ok((_, addr)) => self.web = Some(addr),
                Err(_) => {
                    let _ = self.child.kill();
                    panic!("the simulated module did not report its addresses within 60 s");
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

    /// Stops the module without closing anything (SIGSTOP): the kernel keeps its sockets open
    /// and its listener's backlog accepting, so a client's connect succeeds and its request
    /// waits for an answer that does not come, as with a module that hangs or a cable pulled
    /// mid-exchange (a killed module's sockets refuse and reset at once instead). Returns
    /// whether the module can be [resumed](Self::resume): on Windows, which has no SIGSTOP,
    /// the module is killed instead (connections then fail fast) and this returns `false`.
    pub fn stop(&mut self) -> bool {
        #[cfg(unix)]
        {
            self.signal("-STOP");
            true
        }
        #[cfg(not(unix))]
        {
            // No SIGSTOP on Windows (suspending a process's threads would need its handle's
            // NtSuspendProcess): the fallback is the kill, which a caller must not resume.
            let _ = self.child.kill();
            let _ = self.child.wait();
            false
        }
    }

    /// Lets a module stopped by [`stop`](Self::stop) run again (SIGCONT); it then answers
    /// what waited in its sockets. Nothing to do on Windows (the module was killed).
    pub fn resume(&mut self) {
        #[cfg(unix)]
        self.signal("-CONT");
    }

    #[cfg(unix)]
    fn signal(&self, which: &str) {
        let status = Command::new("kill").arg(which).arg(self.child.id().to_string()).status();
        assert!(status.as_ref().is_ok_and(|s| s.success()), "kill {which} {}: {status:?}", self.child.id());
    }
}

impl Drop for SimModule {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The INFO reply of a module's discovery service at `to` to a search from 127.0.0.1 (its
/// bytes: `remodaq_protocol::discovery::decode_info` reads them).
pub fn search(to: SocketAddr) -> Vec<u8> {
    use remodaq_protocol::discovery::{encode_request, Request, MAX_DATAGRAM};
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").expect("a UDP socket");
    socket.set_read_timeout(Some(Duration::from_secs(5))).expect("a timeout");
    let mut request = [0u8; MAX_DATAGRAM];
    let n = encode_request(1, &Request::Search, &mut request).expect("a search fits");
    socket.send_to(&request[..n], to).expect("sent");
    let mut reply = [0u8; MAX_DATAGRAM];
    let (n, _) = socket.recv_from(&mut reply).expect("an INFO reply");
    reply[..n].to_vec()
}
