//! Running the tool under test: this build's `remodaq`, or the one in `REMODAQ_E2E_BIN_DIR`
//! through `REMODAQ_E2E_RUNNER` (the Windows build under Wine; see
//! `remodaq_board_host::testing`).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use remodaq_board_host::testing::{command, program};

/// Wine's status for a program whose DLLs failed to initialize: STATUS_DLL_INIT_FAILED
/// (0xC0000142), of which a Unix exit status keeps the low byte. Wine says so only on its
/// debug channel (`err:module`), which `WINEDEBUG=-all` silences.
const WINE_DLL_INIT_FAILED: i32 = 0x42;

/// Starts made again in this test binary (see [`remodaq`]).
static RETRIES: AtomicUsize = AtomicUsize::new(0);

/// Runs `remodaq args` with the environment `env` (and without `REMODAQ_PASSWORD` unless
/// given), bounded to 60 s: exit status, stdout, stderr. Prints the session for the test log.
///
/// Under a runner (Wine) one thing is made again: a start that never reached the program.
/// Wine can fail a process before its `main` (a DLL that failed to initialize: status 66, no
/// output); the program proves it started by creating the file `REMODAQ_START_MARKER` names
/// first thing. A run is made again only when it exited 66, said nothing, left no marker, and
/// is a command that changes nothing (search, read, watch, --version); at most once per test
/// binary (a second one fails the test), each one said on standard error and, when
/// `REMODAQ_E2E_RETRY_LOG` names a file, appended to it (scripts/test counts them:
/// `wine-retries: N`).
pub fn remodaq(args: &[&str], env: &[(&str, &str)]) -> (i32, String, String) {
    let runner = std::env::var_os("REMODAQ_E2E_RUNNER").is_some_and(|r| !r.is_empty());
    loop {
        let marker = start_marker();
        let result = run_remodaq(args, env, &marker);
        let (code, stdout, stderr) = &result;
        let started = marker.exists();
        let _ = std::fs::remove_file(&marker);
        if !(runner && *code == WINE_DLL_INIT_FAILED && stdout.is_empty() && stderr.is_empty() && !started) {
            return result;
        }
        let what = format!("remodaq {} exited {code} without output, before its main", args.join(" "));
        assert!(read_only(args), "{what}: not made again, as it is a command that changes state");
        let retries = RETRIES.fetch_add(1, Ordering::SeqCst) + 1;
        eprintln!("wine-retries: {what} ({retries} in this test binary)");
        if let Some(log) = std::env::var_os("REMODAQ_E2E_RETRY_LOG") {
            let mut file = std::fs::OpenOptions::new().create(true).append(true).open(log).expect("the retry log");
            writeln!(file, "{what}").expect("the retry log");
        }
        assert!(retries <= 1, "{what}: the second start in this test binary that never reached remodaq");
    }
}

/// A command that changes nothing in a module or on this PC, so that a second run is harmless:
/// `search`, `read`, `watch`, or `--version`, after the global options.
fn read_only(args: &[&str]) -> bool {
    let mut rest = args.iter();
    while let Some(a) = rest.next() {
        match *a {
            "--json" => {}
            "--timeout" | "--interface" => {
                rest.next();
            }
            "search" | "read" | "watch" | "--version" => return true,
            _ => return false,
        }
    }
    false
}

/// A fresh path for the start marker of one run (as the program under the runner names it:
/// Wine's drive Z: is this machine's root).
fn start_marker() -> PathBuf {
    static N: AtomicUsize = AtomicUsize::new(0);
    let dir = std::env::temp_dir().join(format!("remodaq-e2e-markers-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join(format!("started-{}", N.fetch_add(1, Ordering::SeqCst)));
    let _ = std::fs::remove_file(&path);
    path
}

fn run_remodaq(args: &[&str], env: &[(&str, &str)], marker: &Path) -> (i32, String, String) {
    let tool = program("remodaq", Path::new(env!("CARGO_BIN_EXE_remodaq")));
    let runner = std::env::var_os("REMODAQ_E2E_RUNNER").is_some_and(|r| !r.is_empty());
    // Under Wine the program names the file by its Windows path: Z: is this machine's root.
    let marker = if runner { format!("Z:{}", marker.display()) } else { marker.display().to_string() };
    let mut child = command(&tool)
        .args(args)
        .env_remove("REMODAQ_PASSWORD")
        .env("REMODAQ_START_MARKER", marker)
        .envs(env.iter().copied())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run remodaq");
    let deadline = Instant::now() + Duration::from_secs(60);
    while child.try_wait().expect("wait").is_none() {
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("remodaq {args:?} did not finish within 60 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = child.wait_with_output().expect("output");
    let (stdout, stderr) =
        (String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr).into_owned());
    eprintln!("$ remodaq {}\n{stdout}{stderr}", args.join(" "));
    (out.status.code().unwrap_or(-1), stdout, stderr)
}
