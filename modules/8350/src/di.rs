//! The digital-input engine (spec §3.3): all twelve inputs processed together from a stream of
//! port snapshots taken at a fixed sample rate (bit n of a sample = DIn).
//!
//! The hardware path captures (a timer-paced DMA of the input port into a ring buffer on the
//! STM32 board, a generator in simulated time on the host board) and this engine catches up
//! with whatever has been captured, so edges are never lost while the network is busy as long
//! as the ring does not overrun. Limits: a level must last at least one sample to be seen, so
//! a 50 % square wave is counted exactly up to half the sample rate (25 kHz at the STM32
//! board's 50 kHz), and any pulse or gap shorter than one sample period (20 µs) may be missed;
//! beyond that the cost per sample (see `tools/m4-cost`) bounds the sample rate.

/// The input sample rate of the boards (STM32 capture and host simulation), Hz.
pub const SAMPLE_RATE_HZ: u32 = 50_000;

/// Number of digital inputs.
pub const CHANNELS: usize = remodaq_protocol::m8350::DI_CHANNELS;
/// The bits of a sample that are inputs.
pub const MASK: u16 = (1 << CHANNELS) - 1;

pub use remodaq_protocol::m8350::DiMode;

/// The engine: per-channel counters and flags kept as bit masks, so a sample without edges
/// costs a compare and the gate countdown.
pub struct DiEngine {
    modes: [DiMode; CHANNELS],
    counts: [u32; CHANNELS],
    gate_counts: [u32; CHANNELS],
    frequency: [u32; CHANNELS],
    state: u16,
    run: u16,
    overflow: u16,
    latch: u16,
    /// Channels whose rising edges are counted: counter mode with run = 1, or frequency mode.
    counting: u16,
    frequency_mode: u16,
    latch_rising: u16,
    latch_falling: u16,
    /// Frequency channels whose current gate started before their mode did.
    partial_gate: u16,
    samples_per_gate: u32,
    gate_left: u32,
    /// False until the first sample: it sets the state without edges.
    primed: bool,
}

impl DiEngine {
    /// An engine for samples taken `sample_rate` times a second (the frequency gate is exactly
    /// that many samples). All channels in normal mode, run bits 1, flags clear.
    pub fn new(sample_rate: u32) -> Self {
        let samples_per_gate = sample_rate.max(1);
        Self {
            modes: [DiMode::Normal; CHANNELS],
            counts: [0; CHANNELS],
            gate_counts: [0; CHANNELS],
            frequency: [0; CHANNELS],
            state: 0,
            run: MASK,
            overflow: 0,
            latch: 0,
            counting: 0,
            frequency_mode: 0,
            latch_rising: 0,
            latch_falling: 0,
            partial_gate: 0,
            samples_per_gate,
            gate_left: samples_per_gate,
            primed: false,
        }
    }

    /// Processes captured samples, oldest first.
    pub fn process(&mut self, samples: &[u16]) {
        let mut rest = samples;
        if !self.primed {
            let Some((first, tail)) = rest.split_first() else { return };
            self.state = first & MASK;
            self.primed = true;
            self.count_gate(1);
            rest = tail;
        }
        while !rest.is_empty() {
            let n = rest.len().min(self.gate_left as usize);
            let (chunk, tail) = rest.split_at(n);
            for &sample in chunk {
                let sample = sample & MASK;
                let changed = sample ^ self.state;
                if changed != 0 {
                    self.edges(changed & sample, changed & !sample);
                    self.state = sample;
                }
            }
            self.count_gate(n as u32);
            rest = tail;
        }
    }

    fn edges(&mut self, rising: u16, falling: u16) {
        self.latch |= (rising & self.latch_rising) | (falling & self.latch_falling);
        let mut bits = rising & self.counting;
        while bits != 0 {
            let n = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            if self.frequency_mode & (1 << n) != 0 {
                self.gate_counts[n] += 1;
            } else {
                let (v, wrapped) = self.counts[n].overflowing_add(1);
                self.counts[n] = v;
                if wrapped {
                    self.overflow |= 1 << n;
                }
            }
        }
    }

    fn count_gate(&mut self, n: u32) {
        self.gate_left -= n;
        if self.gate_left > 0 {
            return;
        }
        self.gate_left = self.samples_per_gate;
        for ch in 0..CHANNELS {
            let bit = 1 << ch;
            if self.frequency_mode & bit != 0 && self.partial_gate & bit == 0 {
                self.frequency[ch] = self.gate_counts[ch];
            }
            self.gate_counts[ch] = 0;
        }
        self.partial_gate = 0;
    }

    fn update_masks(&mut self) {
        let mut counter = 0;
        self.frequency_mode = 0;
        self.latch_rising = 0;
        self.latch_falling = 0;
        for (ch, mode) in self.modes.iter().enumerate() {
            let bit = 1 << ch;
            match mode {
                DiMode::Normal => {}
                DiMode::Counter => counter |= bit,
                DiMode::LatchRising => self.latch_rising |= bit,
                DiMode::LatchFalling => self.latch_falling |= bit,
                DiMode::Frequency => self.frequency_mode |= bit,
            }
        }
        self.counting = (counter & self.run) | self.frequency_mode;
    }

    /// Input states, bit n = DIn (the latest sample).
    pub fn state(&self) -> u16 {
        self.state
    }

    /// Mode of channel `n`.
    pub fn mode(&self, n: usize) -> DiMode {
        self.modes[n % CHANNELS]
    }

    /// Sets channel `n`'s mode; a change clears its counter, frequency and flags.
    pub fn set_mode(&mut self, n: usize, mode: DiMode) {
        let n = n % CHANNELS;
        if self.modes[n] == mode {
            return;
        }
        self.modes[n] = mode;
        self.counts[n] = 0;
        self.gate_counts[n] = 0;
        self.frequency[n] = 0;
        self.overflow &= !(1 << n);
        self.latch &= !(1 << n);
        // A gate that has already counted samples in the old mode is not published; a change
        // at a gate's start (or before the first sample) loses nothing.
        if self.gate_left < self.samples_per_gate {
            self.partial_gate |= 1 << n;
        }
        self.update_masks();
    }

    /// The counter register of channel `n`: the count, or the frequency (Hz) in frequency mode.
    pub fn counter_value(&self, n: usize) -> u32 {
        let n = n % CHANNELS;
        if self.modes[n] == DiMode::Frequency {
            self.frequency[n]
        } else {
            self.counts[n]
        }
    }

    /// Run bit of channel `n`.
    pub fn run(&self, n: usize) -> bool {
        self.run & (1 << (n % CHANNELS)) != 0
    }

    /// Starts (true) or stops (false) channel `n`'s counter.
    pub fn set_run(&mut self, n: usize, run: bool) {
        let bit = 1 << (n % CHANNELS);
        if run {
            self.run |= bit;
        } else {
            self.run &= !bit;
        }
        self.update_masks();
    }

    /// Clears channel `n`'s counter.
    pub fn clear_counter(&mut self, n: usize) {
        self.counts[n % CHANNELS] = 0;
    }

    /// Channel `n`'s overflow flag; reading clears it.
    pub fn take_overflow(&mut self, n: usize) -> bool {
        take(&mut self.overflow, n)
    }

    /// Channel `n`'s latch flag; reading clears it.
    pub fn take_latch(&mut self, n: usize) -> bool {
        take(&mut self.latch, n)
    }

    /// The overflow and latch flags, bit n = DIn, without clearing them (diagnostics and
    /// tests; Modbus reads clear them through [`Self::take_overflow`], [`Self::take_latch`]).
    pub fn flags(&self) -> (u16, u16) {
        (self.overflow, self.latch)
    }

    /// Clears channel `n`'s overflow flag.
    pub fn clear_overflow(&mut self, n: usize) {
        self.overflow &= !(1 << (n % CHANNELS));
    }

    /// Clears channel `n`'s latch flag.
    pub fn clear_latch(&mut self, n: usize) {
        self.latch &= !(1 << (n % CHANNELS));
    }

    /// Presets channel `n`'s counter (tests of the overflow).
    pub fn preset_counter(&mut self, n: usize, value: u32) {
        self.counts[n % CHANNELS] = value;
    }
}

fn take(flags: &mut u16, n: usize) -> bool {
    let bit = 1 << (n % CHANNELS);
    let set = *flags & bit != 0;
    *flags &= !bit;
    set
}
