//! The stacks' high-water marks in QEMU's log, against the memory plan (docs/design.md "Memory
//! plan", "Three executors"): the main stack's, and the background executor's with it.

/// The stack the memory plan keeps (docs/design.md, "Memory plan"): of the 1 MiB part's 128 KiB
/// of SRAM1+2, what the statics leave, at least this (`scripts/size-report` checks the statics).
/// Held: both models' peaks fit it (issue #39; the 8350's came down from about 50 KB once the
/// web console's answers stopped travelling by value, docs/design.md "Memory plan").
const PLAN_STACK: usize = 32 * 1024;

/// The highest of the QEMU board's stack high-water marks in its log (each rise, and again
/// from the paint after each restart): within the painted stack with 1 KiB to spare (more
/// would have run into the statics below it), and within [`PLAN_STACK`].
pub(crate) fn stack_mark(model: &str, log: &str) -> Result<(), String> {
    let text = std::fs::read_to_string(log).map_err(|e| format!("QEMU's log {log}: {e}"))?;
    let Some((most, size)) = highest(&text, MAIN_MARK) else {
        return Err("no stack high-water mark in QEMU's log".into());
    };
    println!(
        "qemu-{model}: stack high-water mark {most} of {size} bytes at the most (the memory plan keeps {PLAN_STACK})"
    );
    if most + 1024 > size {
        Err(format!("{most} of {size} bytes: less than 1 KiB to spare"))
    } else if most > PLAN_STACK {
        Err(format!("{most} bytes: over the {PLAN_STACK} bytes the memory plan keeps"))
    } else {
        Ok(())
    }
}

/// What comes before the main stack's high-water mark in QEMU's log (`... N of M bytes`).
const MAIN_MARK: &str = "stack high-water mark ";
/// What comes before the background executor's (`... N of M bytes at the most`).
const BACKGROUND_MARK: &str = "the background executor's stack used ";

/// The highest of the marks that follow `mark` in QEMU's log `text` (`N of M`): (N, M).
fn highest(text: &str, mark: &str) -> Option<(usize, usize)> {
    text.lines()
        .filter_map(|l| {
            let mut words = l.split(mark).nth(1)?.split(' ');
            Some((words.next()?.parse().ok()?, words.nth(1)?.parse().ok()?))
        })
        .max()
}

/// QEMU's log at `log` (empty when it cannot be read).
fn read_log(log: &str) -> String {
    String::from_utf8_lossy(&std::fs::read(log).unwrap_or_default()).into_owned()
}

/// The STM32 board runs the background executor on the main stack (`remodaq_board_stm32::
/// executor`), where its deepest calls may come on top of the deepest of the main side's: the
/// two high-water marks the QEMU board measures apart (`background` bytes, and the main stack's
/// in `log`) must fit the memory plan's stack together.
pub(crate) fn shares_the_plan(background: usize, log: &str) -> Result<(), String> {
    let Some((main, _)) = highest(&read_log(log), MAIN_MARK) else {
        return Err("no stack high-water mark in QEMU's log".into());
    };
    let both = main + background;
    println!(
        "  the main stack's high-water mark {main} bytes, with the background's {both} bytes (the memory plan's stack {}, one stack on the STM32)",
        PLAN_STACK
    );
    if both > PLAN_STACK {
        return Err(format!(
            "the main stack's high-water mark and the background executor's, {both} bytes, over the memory plan's {}",
            PLAN_STACK
        ));
    }
    Ok(())
}

/// The background executor's stack as QEMU's log says it at the most (`the background executor's
/// stack used N of M bytes`): (N, M), or zeros.
pub(crate) fn background_stack(log: &str) -> (usize, usize) {
    highest(&read_log(log), BACKGROUND_MARK).unwrap_or((0, 0))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The memory plan's 32 KiB (issue #39) is held: the 8350's peak of the previous stop
    /// (49 912 bytes) fails, one within it passes; and the 1 KiB spare below the statics.
    #[test]
    fn the_stack_mark_is_held_to_the_plan() {
        let log = std::env::temp_dir().join(format!("qemu-e2e-stack-{}.log", std::process::id()));
        let mark = |most: usize, size: usize| {
            std::fs::write(&log, format!("x\nstack high-water mark {most} of {size} bytes\n")).unwrap();
            stack_mark("8350", log.to_str().unwrap())
        };
        assert!(mark(24_572, 79_748).is_ok());
        assert!(mark(49_912, 79_748).unwrap_err().contains("over the 32768 bytes"));
        assert!(mark(20_000, 20_500).unwrap_err().contains("less than 1 KiB"));
        let _ = std::fs::remove_file(&log);
    }

    /// The two stacks' marks together against the memory plan's 32 KiB (the STM32's one stack):
    /// the main stack's highest mark in the log counts, not its first.
    #[test]
    fn both_stacks_fit_the_plan_together() {
        let log = std::env::temp_dir().join(format!("qemu-e2e-stacks-{}.log", std::process::id()));
        let path = log.to_str().unwrap();
        std::fs::write(&log, "qemu board: stack high-water mark 12000 of 72916 bytes\nqemu board: stack high-water mark 19608 of 72916 bytes\n").unwrap();
        assert!(shares_the_plan(8448, path).is_ok());
        assert!(shares_the_plan(32_768 - 19_608, path).is_ok());
        assert!(shares_the_plan(32_768 - 19_608 + 1, path).unwrap_err().contains("over the memory plan's 32768"));
        std::fs::write(&log, "nothing\n").unwrap();
        assert!(shares_the_plan(8448, path).is_err());
        let _ = std::fs::remove_file(&log);
    }
}
