//! The 8350's digital I/O on this board, both paced by hardware timers so that timing never
//! depends on when a task runs:
//!
//! - Inputs DI0-DI11 on PE2-PE13 (pull-down). TIM1's update event, 50 000 times a second,
//!   triggers DMA2 stream 5 (channel 6) to copy GPIOE's input register into a 4096-sample
//!   circular buffer (82 ms); the input task drains it every few ms. Edges are lost only if the
//!   task falls 82 ms behind, and that is detected and logged (overrun).
//! - Outputs DO0-DO5 on PF12, PF13, PF14, PF15, PF3, PF5. TIM8's update event, 10 000 times a
//!   second (the pulse engine's 0.1 ms tick), triggers DMA2 stream 1 (channel 7) to copy one
//!   word per tick from a 128-tick circular pattern into GPIOF's set/reset register; the output
//!   task refills each half as it is played. A 5 kHz train is exact however busy the CPU is. An
//!   output command is written into the queued words from 3 ticks after the DMA's position
//!   (read from NDTR), so it reaches the pin 0.3-0.4 ms after the output task runs. The margin
//!   against the DMA is at least 0.2 ms, not 0.3: in direct mode the stream has already fetched
//!   the word at NDTR before its request (RM0090 §10.3.11, "Direct mode"), so that word is
//!   spent; the latency counted from NDTR under-reports by up to one tick (stm32 review N1).

use embassy_stm32::dma::{Channel, ReadableRingBuffer, TransferOptions, WritableRingBuffer};
use embassy_stm32::gpio::{Input, Level, Output, Pull, Speed};
use embassy_stm32::peripherals::{DMA2_CH1, DMA2_CH5, TIM1, TIM8};
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::low_level::{RoundTo, Timer};
use embassy_stm32::{bind_interrupts, dma, pac};
use remodaq_8350::di::SAMPLE_RATE_HZ;
use remodaq_8350::io::{InputCapture, OutputPattern, PatternUnderrun, SamplesLost, FORCE_AHEAD, OUTPUT_CHUNK};
use remodaq_8350::pulse::TICK_HZ;
use remodaq_8350::M8350;
use remodaq_shared::board::IoFor;
use static_cell::StaticCell;

use crate::resources::{DigitalPeripherals, Io};
use crate::Stm32Board;

bind_interrupts!(struct Irqs {
    DMA2_STREAM5 => dma::InterruptHandler<DMA2_CH5>;
    DMA2_STREAM1 => dma::InterruptHandler<DMA2_CH1>;
});

/// Capture ring, samples (82 ms at the module's 50 kHz).
const CAPTURE_LEN: usize = remodaq_8350::io::CAPTURE_RING;
/// Output pattern ring, ticks: two of the module's refill chunks.
const PATTERN_LEN: usize = 2 * OUTPUT_CHUNK;
/// DMA request (channel selection) of TIM1_UP on DMA2 stream 5, TIM8_UP on DMA2 stream 1.
const TIM1_UP_REQUEST: u8 = 6;
const TIM8_UP_REQUEST: u8 = 7;
/// GPIOF bit of DO n.
const DO_PINS: [u8; 6] = [12, 13, 14, 15, 3, 5];
/// GPIOE bit of DI0.
const DI_SHIFT: u16 = 2;

/// The running input capture.
pub struct Capture {
    ring: ReadableRingBuffer<'static, u16>,
    _pins: [Input<'static>; 12],
    _timer: Timer<'static, TIM1>,
}

impl InputCapture for Capture {
    fn read(&mut self, out: &mut [u16]) -> Result<usize, SamplesLost> {
        match self.ring.read(out) {
            Ok((n, _)) => {
                for s in &mut out[..n] {
                    *s = (*s >> DI_SHIFT) & 0x0FFF;
                }
                Ok(n)
            }
            Err(_) => {
                self.ring.clear();
                Err(SamplesLost)
            }
        }
    }
}

/// The running output pattern.
pub struct Pattern {
    ring: WritableRingBuffer<'static, u32>,
    /// The ring's memory, for rewriting queued ticks in place ([`OutputPattern::force`]).
    words: *mut u32,
    _pins: [Output<'static>; 6],
    _timer: Timer<'static, TIM8>,
}

// SAFETY: `words` points into the 'static ring memory this pattern alone owns (the DMA reads
// it, nothing else writes it); moving the pattern to the realtime executor's interrupt moves
// that ownership with it.
unsafe impl Send for Pattern {}

/// The set/reset bits of the DOs in `mask` (bit n = DOn): both halves of each pin.
fn bsrr_pins(mask: u8) -> u32 {
    DO_PINS.iter().enumerate().filter(|(n, _)| mask >> n & 1 == 1).fold(0, |word, (_, pin)| word | 0x1_0001 << pin)
}

/// The set/reset word of one tick's levels (bit n = DOn).
fn bsrr(levels: u8) -> u32 {
    DO_PINS.iter().enumerate().fold(
        0,
        |word, (n, pin)| {
            if levels >> n & 1 == 1 {
                word | 1 << pin
            } else {
                word | 1 << (pin + 16)
            }
        },
    )
}

impl Pattern {
    /// Ticks queued and not played yet (the ring's capacity less its free room), or `None`
    /// when the ring overran.
    fn queued(&mut self) -> Option<usize> {
        self.ring.len().ok().map(|free| PATTERN_LEN.saturating_sub(free))
    }
}

impl OutputPattern for Pattern {
    async fn room(&mut self) {
        core::future::poll_fn(|cx| {
            self.ring.set_waker(cx.waker());
            match self.ring.len() {
                Ok(free) if free < OUTPUT_CHUNK => core::task::Poll::Pending,
                // Room, or an overrun that `write` reports.
                _ => core::task::Poll::Ready(()),
            }
        })
        .await
    }

    fn write(&mut self, levels: &[u8]) -> Result<u32, PatternUnderrun> {
        let mut words = [0u32; OUTPUT_CHUNK];
        let n = levels.len().min(words.len());
        for (w, l) in words.iter_mut().zip(&levels[..n]) {
            *w = bsrr(*l);
        }
        let ahead = self.queued();
        match (ahead, self.ring.write(&words[..n])) {
            (Some(ahead), Ok(_)) => Ok(ahead as u32),
            _ => {
                self.ring.clear();
                Err(PatternUnderrun)
            }
        }
    }

    fn force(&mut self, mask: u8, levels: u8) -> u32 {
        let Some(queued) = self.queued() else { return 0 };
        let ahead = FORCE_AHEAD as usize;
        if queued <= ahead {
            return queued as u32;
        }
        // The word the DMA transfers next: NDTR counts the transfers left in the pass over the
        // circular buffer and is reloaded with its length at the end of each (RM0090 §10.3.9
        // "Circular mode", §10.5.6 DMA_SxNDTR). Stream 1 of DMA2 (TIM8_UP, see `start`).
        let ndtr = || usize::from(pac::DMA2.st(1).ndtr().read().ndt()).min(PATTERN_LEN);
        let left = ndtr();
        let next = (PATTERN_LEN - left) % PATTERN_LEN;
        let pins = bsrr_pins(mask);
        let new = bsrr(levels) & pins;
        for k in ahead..queued {
            let i = (next + k) % PATTERN_LEN;
            // SAFETY: `words` is the ring's 'static buffer of PATTERN_LEN words and i is below
            // PATTERN_LEN. The words from the DMA's next one (plus FORCE_AHEAD ticks of margin,
            // at least 0.2 ms given the word the stream has prefetched) to the ring's write index are queued: the DMA has not read them yet and
            // embassy's ring writes only after its write index, so nothing else writes them now.
            // Every access to the buffer, embassy's and these, is volatile.
            unsafe {
                let word = self.words.add(i);
                word.write_volatile((word.read_volatile() & !pins) | new);
            }
        }
        // Interrupts stay on: if the DMA moved past the margin meanwhile, a tick or more
        // played the old level between new ones. Said, not hidden.
        let moved = (left + PATTERN_LEN - ndtr()) % PATTERN_LEN;
        if moved >= ahead {
            remodaq_shared::warn!("outputs: a forced rewrite outran its margin ({} ticks)", moved);
        }
        FORCE_AHEAD
    }
}

impl IoFor<M8350> for Stm32Board {
    type Io = (Capture, Pattern);

    fn io(resources: Io) -> (Capture, Pattern) {
        resources.digital.start()
    }
}

impl DigitalPeripherals {
    /// Starts capture and output; the pattern starts with every output off (spec §3.4).
    pub fn start(self) -> (Capture, Pattern) {
        let pins = self.di.map(|pin| Input::new(pin, Pull::Down));
        // DMA2 writes it: in SRAM, checked at link time (memory.x).
        #[unsafe(export_name = "REMODAQ_DMA_CAPTURE")]
        static CAPTURE: StaticCell<[u16; CAPTURE_LEN]> = StaticCell::new();
        let buffer = CAPTURE.init([0; CAPTURE_LEN]);
        // SAFETY: GPIOE's input register is a valid, always-readable peripheral address; the
        // buffer is 'static and owned by the ring from here on.
        let mut ring = unsafe {
            ReadableRingBuffer::new(
                Channel::new(self.dma_in, Irqs),
                TIM1_UP_REQUEST,
                pac::GPIOE.idr().as_ptr() as *mut u16,
                buffer,
                TransferOptions::default(),
            )
        };
        ring.start();
        let timer = Timer::new(self.tim_in);
        timer.set_frequency(Hertz(SAMPLE_RATE_HZ), RoundTo::Slower);
        timer.enable_update_dma(true);
        timer.start();
        let capture = Capture { ring, _pins: pins, _timer: timer };

        let outputs = self.outputs.map(|pin| Output::new(pin, Level::Low, Speed::High));
        // DMA2 reads it: in SRAM, checked at link time (memory.x).
        #[unsafe(export_name = "REMODAQ_DMA_PATTERN")]
        static PATTERN: StaticCell<[u32; PATTERN_LEN]> = StaticCell::new();
        let buffer = PATTERN.init([bsrr(0); PATTERN_LEN]);
        let words = buffer.as_mut_ptr();
        // SAFETY: GPIOF's set/reset register is a valid, write-only peripheral address whose
        // writes only change the pins of its set bits; the buffer is 'static.
        let mut ring = unsafe {
            WritableRingBuffer::new(
                Channel::new(self.dma_out, Irqs),
                TIM8_UP_REQUEST,
                pac::GPIOF.bsrr().as_ptr() as *mut u32,
                buffer,
                TransferOptions::default(),
            )
        };
        ring.start();
        let timer = Timer::new(self.tim_out);
        timer.set_frequency(Hertz(TICK_HZ), RoundTo::Slower);
        timer.enable_update_dma(true);
        timer.start();
        (capture, Pattern { ring, words, _pins: outputs, _timer: timer })
    }
}
