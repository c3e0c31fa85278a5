//! The run's report: each check's line, the counts of passed and failed checks, and how many
//! checks a run of each model declares.

pub(crate) struct Report {
    pub(crate) model: String,
    pub(crate) passed: u32,
    pub(crate) failed: u32,
}

/// How many checks a run of each model makes (`run` and `updates`): a run that stops early
/// (no boot, missing update images) counts every check it did not make as failed.
pub(crate) fn checks_of(model: u16) -> u32 {
    match model {
        0x8318 => 12,
        0x8350 => 29,
        _ => 0,
    }
}

impl Report {
    /// Counts every declared check that did not run as failed, and a run that made more
    /// checks than declared as one more failure (the declaration is out of date).
    pub(crate) fn finish(&mut self, declared: u32) {
        let made = self.passed + self.failed;
        if made < declared {
            println!("qemu-{}: {} checks not run, counted as failed", self.model, declared - made);
            self.failed += declared - made;
        } else if made > declared {
            self.check("the number of checks", Err(format!("{made} made, {declared} declared in checks_of")));
        }
    }

    pub(crate) fn check(&mut self, name: &str, result: Result<(), String>) {
        match result {
            Ok(()) => {
                self.passed += 1;
                println!("qemu-{} {name} ... ok", self.model);
            }
            Err(e) => {
                self.failed += 1;
                println!("qemu-{} {name} ... FAILED: {e}", self.model);
            }
        }
    }
}
