//! The Modbus latency the guest measured itself (the QEMU board's `probe`: from the interrupt
//! that brought a request to its answer written to the NIC, on the guest's clock), read back
//! from QEMU's log once the measured connection ends. Under `-icount` (`start_qemu_counted`) the
//! guest's clock counts its instructions, so the figure is the firmware's alone.

use std::time::{Duration, Instant};

/// One connection's figures, µs of the guest's clock.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Guest {
    pub(crate) requests: usize,
    pub(crate) median: u32,
    pub(crate) p99: u32,
    pub(crate) worst: u32,
}

impl std::fmt::Display for Guest {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "median {} us, 99 % {} us, worst {} us", self.median, self.p99, self.worst)
    }
}

/// The board's line for a connection (`qemu board: Modbus answers to the client at port P: N
/// requests, median A us, 99 % B us, worst C us`), if `line` is one.
fn parse(line: &str) -> Option<Guest> {
    let rest = line.strip_prefix("qemu board: Modbus answers to the client at port ")?;
    let (_, rest) = rest.split_once(": ")?;
    let words: Vec<&str> = rest.split([' ', ',']).filter(|w| !w.is_empty()).collect();
    // N requests median A us 99 % B us worst C us
    match words.as_slice() {
        [n, "requests", "median", a, "us", "99", "%", b, "us", "worst", c, "us"] => Some(Guest {
            requests: n.parse().ok()?,
            median: a.parse().ok()?,
            p99: b.parse().ok()?,
            worst: c.parse().ok()?,
        }),
        _ => None,
    }
}

/// The first connection of `requests` requests that QEMU's log `log` says after byte `from`,
/// waited for up to 3 s (the board says it when the connection's FIN reaches it).
pub(crate) async fn figures(log: &str, from: u64, requests: usize) -> Option<Guest> {
    let deadline = Instant::now() + Duration::from_secs(3);
    loop {
        let text = std::fs::read(log).unwrap_or_default();
        let text = String::from_utf8_lossy(text.get(from as usize..).unwrap_or(&[]));
        if let Some(g) = text.lines().filter_map(parse).find(|g| g.requests == requests) {
            return Some(g);
        }
        if Instant::now() > deadline {
            return None;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// The guest's figures with MQTT off and on, side by side, and the worsts' ratio.
pub(crate) fn compared(off: Option<Guest>, on: Option<Guest>) -> String {
    match (off, on) {
        (Some(off), Some(on)) => {
            format!("off: {off}; on: {on} (worst {:.2}x off's)", f64::from(on.worst) / f64::from(off.worst.max(1)))
        }
        _ => format!("not in QEMU's log (off: {off:?}, on: {on:?})"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_boards_line() {
        let line = "qemu board: Modbus answers to the client at port 41810: 1000 requests, median 103 us, 99 % 425 us, worst 523 us";
        assert_eq!(parse(line), Some(Guest { requests: 1000, median: 103, p99: 425, worst: 523 }));
        assert_eq!(parse("qemu board: a task poll of the main executor took 3221 us, at 8544 us"), None);
    }
}
