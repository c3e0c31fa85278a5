//! The machine's stalls, the firmware's critical sections and the output ring's underruns, as
//! the QEMU board says them in QEMU's log, and which underruns they explain.

/// A gap of over 5 ms between two SysTicks, as the QEMU board says it (`time.rs`): when it
/// ended, how long it was, and how much of it the firmware's critical sections held
/// (interrupts masked), µs of the guest's clock.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Stall {
    at: u64,
    gap: u64,
    pub(crate) masked: u64,
}

impl Stall {
    /// The time this PC took from the machine: the gap less the 1 ms SysTick period and less
    /// the firmware's critical sections. Only interrupts masked or the machine not running
    /// delay SysTick, and the board measures the first; so a stall a critical section covered
    /// excuses nothing (a critical section held 10 ms is the firmware's, however the log calls
    /// the gap it made). A PC that stopped QEMU during a critical section is counted as the
    /// firmware's too: the error is on the side of failing.
    pub(crate) fn lost(&self) -> u64 {
        self.gap.saturating_sub(1_000 + self.masked)
    }
}

/// The machine's stalls and the output ring's underruns (when, µs of the guest's clock) in a
/// part of QEMU's log (boards/qemu: `time.rs`, `digital.rs`). A stall line without its
/// critical sections (a board before they were measured) counts them as the whole gap: it
/// excuses nothing.
pub(crate) fn stalls_and_underruns(log: &str) -> (Vec<Stall>, Vec<u64>) {
    let number = |text: &str, after: &str| {
        text.split(after).nth(1).and_then(|r| r.split(' ').next()).and_then(|n| n.parse::<u64>().ok())
    };
    let (mut stalls, mut dry) = (vec![], vec![]);
    for line in log.lines() {
        if line.starts_with("qemu board: the machine stalled") {
            if let (Some(gap), Some(at)) = (number(line, "stalled "), number(line, ", at ")) {
                let masked = number(line, "; critical sections ").unwrap_or(gap);
                stalls.push(Stall { at, gap, masked });
            }
        } else if line.starts_with("qemu board: the output pattern ran dry") {
            dry.extend(number(line, ", at "));
        }
    }
    (stalls, dry)
}

/// The firmware's critical sections the QEMU board said in a part of QEMU's log: each new
/// longest of 1 ms or more (µs), and the most any stall's gap held.
pub(crate) fn longest_critical_section(log: &str) -> u64 {
    let number = |text: &str, after: &str| {
        text.split(after).nth(1).and_then(|r| r.split(' ').next()).and_then(|n| n.parse::<u64>().ok())
    };
    log.lines()
        .filter_map(|line| {
            if line.starts_with("qemu board: critical section ") {
                number(line, "critical section ")
            } else if line.starts_with("qemu board: the machine stalled") {
                number(line, ", the longest ")
            } else {
                None
            }
        })
        .max()
        .unwrap_or(0)
}

/// The stalls ending from 20 ms before `t` to 2 ms after (the refill that finds the ring dry
/// runs right after the stall; when the stall caught the I/O loop itself, before the SysTick
/// that says it).
fn around(stalls: &[Stall], t: u64) -> impl Iterator<Item = &Stall> {
    stalls.iter().filter(move |s| s.at + 20_000 >= t && s.at <= t + 2_000)
}

/// The time this PC took from the machine ([`Stall::lost`]) in the stalls around `t`, µs.
fn lost_around(stalls: &[Stall], t: u64) -> u64 {
    around(stalls, t).map(Stall::lost).sum()
}

/// The time the firmware's critical sections held in the stalls around `t`, µs.
fn masked_around(stalls: &[Stall], t: u64) -> u64 {
    around(stalls, t).map(|s| s.masked).sum()
}

/// Underruns the machine's stalls do not explain: less than [`EXPLAINS_US`] lost around them
/// outside critical sections, or critical sections around them as long (then the firmware
/// could have made it by itself, whatever this PC did beside).
pub(crate) fn unexplained_underruns(stalls: &[Stall], dry: &[u64]) -> usize {
    dry.iter().filter(|&&t| lost_around(stalls, t) < EXPLAINS_US || masked_around(stalls, t) >= EXPLAINS_US).count()
}

/// Time lost by the machine just before an underrun that explains it: half the output ring's
/// 6.4 ms slack (a firmware that kept the I/O loop waiting would have had to add the rest).
const EXPLAINS_US: u64 = 3_200;

#[cfg(test)]
mod tests {
    use super::*;

    /// Lines as the QEMU board wrote them in a run on a busy PC (the critical sections added
    /// as the board says them now).
    const LOG: &str =
        "qemu board: the machine stalled 8763 us, at 13659892 us; critical sections 12 us, the longest 3 us
qemu board: the output pattern ran dry, at 13669096 us
qemu board: the machine stalled 9325 us, at 13669217 us; critical sections 25 us, the longest 4 us
bootloader: something else
qemu board: the machine stalled 2500 us, at 14496000 us; critical sections 0 us, the longest 0 us
qemu board: the machine stalled 3000 us, at 14500185 us; critical sections 0 us, the longest 0 us
qemu board: the output pattern ran dry, at 14500991 us
qemu board: the machine stalled 2100 us, at 15999000 us; critical sections 0 us, the longest 0 us
qemu board: the output pattern ran dry, at 16000000 us
";

    #[test]
    fn underruns_after_the_machine_lost_time_are_the_pcs() {
        let (stalls, dry) = stalls_and_underruns(LOG);
        assert_eq!(stalls[0], Stall { at: 13_659_892, gap: 8_763, masked: 12 });
        assert_eq!(stalls.len(), 5);
        assert_eq!(dry, [13_669_096, 14_500_991, 16_000_000]);
        // The first follows (or, caught in the I/O loop, precedes by 121 µs) long stalls; the
        // second two short ones that lost 1.5 + 2 ms; the third only 1.1 ms lost.
        assert_eq!(lost_around(&stalls, 14_500_991), 3_500);
        assert_eq!(unexplained_underruns(&stalls, &dry), 1);
        assert_eq!(unexplained_underruns(&[], &dry), 3);
    }

    /// A critical section of the firmware that held SysTick off makes the same gap as a stall of
    /// the PC, and the same underrun; it explains nothing.
    #[test]
    fn a_critical_section_is_the_firmwares() {
        let log = "qemu board: critical section 10012 us, the longest yet, at 13659892 us
qemu board: the machine stalled 10230 us, at 13659892 us; critical sections 10040 us, the longest 10012 us
qemu board: the output pattern ran dry, at 13659990 us
qemu board: the machine stalled 12000 us, at 20000000 us; critical sections 4000 us, the longest 4000 us
";
        let (stalls, dry) = stalls_and_underruns(log);
        assert_eq!(stalls[0].lost(), 0);
        assert_eq!(unexplained_underruns(&stalls, &dry), 1);
        // A stall of this PC just before does not explain an underrun a critical section of the
        // firmware could have made by itself.
        let both = format!(
            "qemu board: the machine stalled 8000 us, at 13650000 us; critical sections 3 us, the longest 2 us\n{log}"
        );
        let (stalls, dry) = stalls_and_underruns(&both);
        assert_eq!(lost_around(&stalls, dry[0]), 6_997);
        assert_eq!(unexplained_underruns(&stalls, &dry), 1);
        // Partly covered: only the part no critical section held is the PC's.
        let (stalls, _) = stalls_and_underruns(log);
        assert_eq!(stalls[1].lost(), 7_000);
        assert_eq!(longest_critical_section(log), 10_012);
        // A line of a board that did not measure them excuses nothing.
        let (old, _) = stalls_and_underruns("qemu board: the machine stalled 8763 us, at 13659892 us\n");
        assert_eq!(old, [Stall { at: 13_659_892, gap: 8_763, masked: 8_763 }]);
        assert_eq!(old[0].lost(), 0);
    }
}
