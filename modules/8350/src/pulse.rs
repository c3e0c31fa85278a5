//! The output engine (spec §3.4): six outputs, each a level (normal mode) or a pulse train
//! (pulse mode), computed tick by tick at 0.1 ms. A board turns the ticks into a pattern that a
//! hardware timer clocks out to the port (STM32: timer-paced DMA into the GPIO set/reset
//! register), so a 5 kHz train stays exact however busy the CPU is; the board only has to
//! refill its buffer in time.
//!
//! One pulse is the high phase (high width) then the low phase (low width), each at least one
//! tick. A train of N > 0 pulses ends after the last pulse's low phase, output off; N = 0 runs
//! until stopped. Width changes apply from the next pulse; a count change at the next start.

/// Number of digital outputs.
pub const CHANNELS: usize = remodaq_protocol::m8350::DO_CHANNELS;
/// The engine's tick: 0.1 ms.
pub const TICK_HZ: u32 = 10_000;

pub use remodaq_protocol::m8350::DoMode;

/// A pulse train's settings, in ticks (0.1 ms).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PulseConfig {
    /// Low phase width (>= 1).
    pub low: u32,
    /// High phase width (>= 1).
    pub high: u32,
    /// Pulses per train; 0 = continuous.
    pub count: u32,
}

impl Default for PulseConfig {
    /// Decision: 1 ms low, 1 ms high (500 Hz), continuous.
    fn default() -> Self {
        Self { low: 10, high: 10, count: 0 }
    }
}

#[derive(Clone, Copy)]
struct Output {
    mode: DoMode,
    /// Normal mode: the DO bit.
    level: bool,
    config: PulseConfig,
    running: bool,
    high_phase: bool,
    ticks_left: u32,
    /// Pulses left including the current one; `None`: continuous.
    pulses_left: Option<u32>,
    /// The low width latched at the current pulse's start.
    low: u32,
    /// A level held (safe or power-on value) until a client writes the DO bit or the mode.
    held: Option<bool>,
}

impl Output {
    const OFF: Self = Self {
        mode: DoMode::Normal,
        level: false,
        config: PulseConfig { low: 10, high: 10, count: 0 },
        running: false,
        high_phase: false,
        ticks_left: 0,
        pulses_left: None,
        low: 1,
        held: None,
    };

    fn start_pulse(&mut self) {
        self.high_phase = true;
        self.ticks_left = self.config.high.max(1);
        self.low = self.config.low.max(1);
    }

    fn level_now(&self) -> bool {
        if let Some(level) = self.held {
            return level;
        }
        match self.mode {
            DoMode::Normal => self.level,
            DoMode::Pulse => self.running && self.high_phase,
        }
    }

    fn advance(&mut self) {
        if !self.running {
            return;
        }
        self.ticks_left -= 1;
        if self.ticks_left > 0 {
            return;
        }
        if self.high_phase {
            self.high_phase = false;
            self.ticks_left = self.low;
            return;
        }
        match self.pulses_left {
            Some(1) => {
                self.running = false;
                self.pulses_left = None;
            }
            Some(n) => {
                self.pulses_left = Some(n - 1);
                self.start_pulse();
            }
            None => self.start_pulse(),
        }
    }
}

/// The six outputs. Outputs are off at power-up.
pub struct PulseEngine {
    outputs: [Output; CHANNELS],
    /// Outputs a command changed (a DO bit, a hold, a mode) since [`PulseEngine::take_commanded`].
    commanded: u8,
}

impl Default for PulseEngine {
    fn default() -> Self {
        Self::new()
    }
}

impl PulseEngine {
    /// All outputs off, normal mode.
    pub const fn new() -> Self {
        Self { outputs: [Output::OFF; CHANNELS], commanded: 0 }
    }

    /// The levels of the next tick (bit n = DOn), then advances one tick.
    pub fn tick(&mut self) -> u8 {
        let mut levels = 0;
        for (n, out) in self.outputs.iter_mut().enumerate() {
            if out.level_now() {
                levels |= 1 << n;
            }
            out.advance();
        }
        levels
    }

    /// The outputs commands changed since [`PulseEngine::take_commanded`] (bit n = DOn).
    pub fn commanded(&self) -> u8 {
        self.commanded
    }

    /// The outputs commands changed since the last call (bit n = DOn), and forgets them.
    pub fn take_commanded(&mut self) -> u8 {
        core::mem::take(&mut self.commanded)
    }

    /// The outputs whose level stays put from the next tick on, and those levels: a held
    /// output, a normal-mode output, a pulse-mode output with no train running (off). An
    /// output running a train is not in the mask.
    pub fn steady(&self) -> (u8, u8) {
        self.outputs.iter().enumerate().fold((0, 0), |(mask, levels), (n, out)| {
            let steady = out.held.is_some() || out.mode == DoMode::Normal || !out.running;
            if steady {
                (mask | 1 << n, levels | u8::from(out.level_now()) << n)
            } else {
                (mask, levels)
            }
        })
    }

    /// Fills `ticks` with the next ticks' levels.
    pub fn fill(&mut self, ticks: &mut [u8]) {
        for t in ticks {
            *t = self.tick();
        }
    }

    /// The levels the next tick will have.
    pub fn levels(&self) -> u8 {
        self.outputs.iter().enumerate().filter(|(_, o)| o.level_now()).fold(0, |acc, (n, _)| acc | 1 << n)
    }

    /// The DO bit of output `n`: its level in normal mode; whether a train runs in pulse mode.
    pub fn do_bit(&self, n: usize) -> bool {
        let out = &self.outputs[n % CHANNELS];
        if let Some(level) = out.held {
            return level;
        }
        match out.mode {
            DoMode::Normal => out.level,
            DoMode::Pulse => out.running,
        }
    }

    /// The DO bits of every output (bit n = DOn), as [`PulseEngine::do_bit`] reads them.
    pub fn do_bits(&self) -> u16 {
        (0..CHANNELS).filter(|n| self.do_bit(*n)).fold(0, |acc, n| acc | 1 << n)
    }

    /// Writes output `n`'s DO bit: a level in normal mode; start (if not running) or stop in
    /// pulse mode. A held level ends.
    pub fn set_do(&mut self, n: usize, on: bool) {
        let out = &mut self.outputs[n % CHANNELS];
        // Commanded (to be written into the ticks already queued): a level, or a train that
        // runs and is stopped. Not a train started (it begins with the next refill, exact), nor
        // a 0 written to a train the engine has finished computing (its last ticks still play).
        if out.held.is_some() || out.mode == DoMode::Normal || (out.running && !on) {
            self.commanded |= 1 << (n % CHANNELS);
        }
        out.held = None;
        match out.mode {
            DoMode::Normal => out.level = on,
            DoMode::Pulse if on && !out.running => {
                out.running = true;
                out.pulses_left = (out.config.count > 0).then_some(out.config.count);
                out.start_pulse();
            }
            DoMode::Pulse if !on => {
                out.running = false;
                out.pulses_left = None;
            }
            DoMode::Pulse => {}
        }
    }

    /// Mode of output `n`.
    pub fn mode(&self, n: usize) -> DoMode {
        self.outputs[n % CHANNELS].mode
    }

    /// Holds every output at its level in `levels` (bit n = DOn), whatever its mode: every
    /// pulse train stops. The DO bits read the held levels until a client writes them (or the
    /// mode). The host watchdog's safe state and the power-on values (extensions §3).
    pub fn hold(&mut self, levels: u8) {
        self.commanded = (1 << CHANNELS) - 1;
        for (n, out) in self.outputs.iter_mut().enumerate() {
            let level = levels >> n & 1 != 0;
            out.running = false;
            out.pulses_left = None;
            out.held = Some(level);
            if out.mode == DoMode::Normal {
                out.level = level;
            }
        }
    }

    /// Sets output `n`'s mode: a change stops any train and turns the output off (a held level
    /// ends).
    pub fn set_mode(&mut self, n: usize, mode: DoMode) {
        let out = &mut self.outputs[n % CHANNELS];
        if out.mode != mode {
            *out = Output { mode, config: out.config, ..Output::OFF };
            self.commanded |= 1 << (n % CHANNELS);
        }
    }

    /// Output `n`'s train settings.
    pub fn config(&self, n: usize) -> PulseConfig {
        self.outputs[n % CHANNELS].config
    }

    /// Sets output `n`'s train settings (widths from the next pulse, count from the next start).
    pub fn set_config(&mut self, n: usize, config: PulseConfig) {
        self.outputs[n % CHANNELS].config = config;
    }

    /// Adds `extra` pulses to output `n`'s running finite train (no effect otherwise).
    pub fn add_pulses(&mut self, n: usize, extra: u32) {
        let out = &mut self.outputs[n % CHANNELS];
        if let (true, Some(left)) = (out.running, out.pulses_left) {
            out.pulses_left = Some(left.saturating_add(extra));
        }
    }
}
