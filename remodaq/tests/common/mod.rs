//! Running the tool under test: this build's `remodaq`, or the one in `REMODAQ_E2E_BIN_DIR`
//! through `REMODAQ_E2E_RUNNER` (the Windows build under Wine; see
//! `remodaq_board_host::testing`).

use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

use remodaq_board_host::testing::{command, program};

/// Runs `remodaq args` with the environment `env` (and without `REMODAQ_PASSWORD` unless
/// given), bounded to 60 s: exit status, stdout, stderr. Prints the session for the test log.
pub fn remodaq(args: &[&str], env: &[(&str, &str)]) -> (i32, String, String) {
    // Under a runner (Wine), a start of the program can fail by itself: no output at all and an
    // exit status remodaq never uses (it exits 0 to 6). Seen once in a CI run (status 66, the
    // command before and after it fine): that start is made again, at most twice, and said.
    let runner = std::env::var_os("REMODAQ_E2E_RUNNER").is_some_and(|r| !r.is_empty());
    let mut result = run_remodaq(args, env);
    for _ in 0..2 {
        let (code, stdout, stderr) = &result;
        if !(runner && !(0..=6).contains(code) && stdout.is_empty() && stderr.is_empty()) {
            break;
        }
        eprintln!("the runner did not start remodaq (status {code}, no output): once more");
        result = run_remodaq(args, env);
    }
    result
}

fn run_remodaq(args: &[&str], env: &[(&str, &str)]) -> (i32, String, String) {
    let tool = program("remodaq", Path::new(env!("CARGO_BIN_EXE_remodaq")));
    let mut child = command(&tool)
        .args(args)
        .env_remove("REMODAQ_PASSWORD")
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
