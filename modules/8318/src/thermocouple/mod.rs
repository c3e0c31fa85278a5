//! Thermocouple reference functions for the eleven types of the 8318 and their inverses.
//!
//! The forward functions (temperature -> emf) are the published reference polynomials, in f64.
//! The inverse (emf -> temperature) is the exact inverse of the forward function, found by a
//! safeguarded Newton iteration on it (Newton steps kept inside a shrinking bracket, bisection
//! when a step would leave it), started from a piecewise-linear first guess. It converges to
//! well below 0.001 °C in a few steps, over each type's whole range, where NIST's own inverse
//! polynomials are good to ±0.05 °C only and leave gaps.
//!
//! f64, not f32: the polynomials reach t^14 with alternating coefficients, and f32 round-off
//! alone costs hundredths of a degree. The Cortex-M4F has no double-precision FPU, so f64 is
//! emulated: `tools/m4-cost` measures 14 900 to 44 700 instructions per conversion (type M to
//! type K), at most 0.25 ms at 180 MHz, so 8 channels at 10 Hz take about 2 % of the CPU.
//! `examples/tc_inverse.rs` reports how exactly the inverse undoes the forward function
//! (1e-7 °C) and how both agree with the NIST tables (within the tables' own rounding).

mod nist;
mod other;
mod piece;

pub use piece::Piece;
pub use remodaq_protocol::m8318::TcType;

/// The result of converting an emf to a temperature.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Inverse {
    /// Below the lowest temperature the reference function covers.
    Below,
    /// Above the highest temperature the reference function covers.
    Above,
    /// The temperature, °C.
    Celsius(f64),
}

/// Type B's emf falls from 0 °C to a minimum here, then rises: below it two temperatures share
/// an emf. The inverse uses the rising branch (decision, documented in the register map).
/// Found by `tests::type_b_minimum` to 1e-6 °C.
pub const B_MINIMUM_C: f64 = 21.020_262;

/// Bound on Newton / bisection steps (bisection alone would need about 45 for 1e-7 °C).
const MAX_ITERATIONS: usize = 60;
/// An emf this close outside the ends of the range is the end itself (float round-off), mV.
const EDGE_MV: f64 = 1e-9;
/// Newton stops when a step is below this, °C.
const STEP_TOLERANCE: f64 = 1e-7;

/// The reference functions of a thermocouple type and their inverses.
pub trait Reference: Copy {
    /// The subranges of the reference function.
    fn pieces(self) -> &'static [Piece];

    /// The temperatures the reference function covers, °C.
    fn defined_range(self) -> (f64, f64);

    /// The range the inverse covers: the defined range, from the minimum for type B.
    fn inverse_range(self) -> (f64, f64);

    /// The emf in mV at `t` °C; `None` outside the defined range.
    fn emf_mv(self, t: f64) -> Option<f64>;

    /// The emf at `t` clamped into the defined range (for the cold junction, whose temperature
    /// may sit just outside it, e.g. type B below 0 °C).
    fn emf_clamped_mv(self, t: f64) -> f64;

    /// Emf (mV) and its slope dE/dt (mV/°C) at `t`, from the subrange holding `t` (the nearest
    /// one outside the range).
    fn emf_and_slope(self, t: f64) -> (f64, f64);

    /// The temperature whose emf is `emf_mv`: the exact inverse of [`Self::emf_mv`].
    fn temperature_c(self, emf_mv: f64) -> Inverse;

    /// [`Self::temperature_c`] and the number of forward evaluations it took.
    fn temperature_with_iterations(self, emf_mv: f64) -> (Inverse, usize);
}

impl Reference for TcType {
    fn pieces(self) -> &'static [Piece] {
        match self {
            TcType::B => nist::B,
            TcType::E => nist::E,
            TcType::J => nist::J,
            TcType::K => nist::K,
            TcType::N => nist::N,
            TcType::R => nist::R,
            TcType::S => nist::S,
            TcType::T => nist::T,
            TcType::C => other::C,
            TcType::L => other::L,
            TcType::M => other::M,
        }
    }

    fn defined_range(self) -> (f64, f64) {
        let pieces = self.pieces();
        (pieces[0].lo, pieces[pieces.len() - 1].hi)
    }

    fn inverse_range(self) -> (f64, f64) {
        let (lo, hi) = self.defined_range();
        if self == TcType::B {
            (B_MINIMUM_C, hi)
        } else {
            (lo, hi)
        }
    }

    fn emf_mv(self, t: f64) -> Option<f64> {
        let (lo, hi) = self.defined_range();
        (lo..=hi).contains(&t).then(|| self.emf_and_slope(t).0)
    }

    fn emf_clamped_mv(self, t: f64) -> f64 {
        let (lo, hi) = self.defined_range();
        // Not `f64::clamp`, whose panic for bounds it cannot prove ordered (these come from a
        // table) formats both floats: 9 KB of float formatting in the image for a panic that
        // cannot happen. The same value (a NaN stays NaN).
        let t = if t < lo {
            lo
        } else if t > hi {
            hi
        } else {
            t
        };
        self.emf_and_slope(t).0
    }

    fn emf_and_slope(self, t: f64) -> (f64, f64) {
        let pieces = self.pieces();
        let piece = pieces.iter().find(|p| t <= p.hi).unwrap_or(&pieces[pieces.len() - 1]);
        // Horner for the value and the derivative together.
        let mut e = 0.0;
        let mut de = 0.0;
        for &c in piece.c.iter().rev() {
            de = de * t + e;
            e = e * t + c;
        }
        if self == TcType::K && t > 0.0 {
            let [a0, a1, a2] = nist::K_EXP;
            let d = t - a2;
            let x = a0 * libm::exp(a1 * d * d);
            e += x;
            de += x * 2.0 * a1 * d;
        }
        (e, de)
    }

    fn temperature_c(self, emf_mv: f64) -> Inverse {
        self.temperature_with_iterations(emf_mv).0
    }

    fn temperature_with_iterations(self, emf_mv: f64) -> (Inverse, usize) {
        if emf_mv.is_nan() {
            return (Inverse::Above, 0);
        }
        let (lo, hi) = self.inverse_range();
        // First guess: the subrange whose end emfs bracket the emf, interpolated linearly.
        let (mut a, mut b) = (lo, hi);
        let (mut ea, mut eb) = (self.emf_and_slope(lo).0, self.emf_and_slope(hi).0);
        let mut evaluations = 2;
        if emf_mv < ea - EDGE_MV {
            return (Inverse::Below, evaluations);
        }
        if emf_mv > eb + EDGE_MV {
            return (Inverse::Above, evaluations);
        }
        if emf_mv <= ea {
            return (Inverse::Celsius(lo), evaluations);
        }
        if emf_mv >= eb {
            return (Inverse::Celsius(hi), evaluations);
        }
        for piece in self.pieces() {
            if piece.hi > a && piece.hi < b {
                let e = self.emf_and_slope(piece.hi).0;
                evaluations += 1;
                if e < emf_mv {
                    (a, ea) = (piece.hi, e);
                } else {
                    (b, eb) = (piece.hi, e);
                }
            }
        }
        let mut t = if eb > ea { a + (emf_mv - ea) * (b - a) / (eb - ea) } else { a };
        for _ in 0..MAX_ITERATIONS {
            let (e, slope) = self.emf_and_slope(t);
            evaluations += 1;
            let r = e - emf_mv;
            if r == 0.0 {
                return (Inverse::Celsius(t), evaluations);
            }
            if r < 0.0 {
                a = t;
            } else {
                b = t;
            }
            let newton = t - r / slope;
            let next = if slope > 0.0 && newton > a && newton < b { newton } else { 0.5 * (a + b) };
            if (next - t).abs() < STEP_TOLERANCE || b - a < STEP_TOLERANCE {
                return (Inverse::Celsius(next), evaluations);
            }
            t = next;
        }
        (Inverse::Celsius(t), evaluations)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn type_b_minimum() {
        // Bisection on the slope between 0 and 100 °C.
        let (mut a, mut b) = (0.0, 100.0);
        for _ in 0..100 {
            let m = 0.5 * (a + b);
            if TcType::B.emf_and_slope(m).1 < 0.0 {
                a = m;
            } else {
                b = m;
            }
        }
        assert!((a - B_MINIMUM_C).abs() < 1e-6, "minimum at {a}");
    }

    #[test]
    fn spot_values() {
        let check = |tc: TcType, t: f64, mv: f64, tol: f64| {
            let e = tc.emf_mv(t).unwrap();
            assert!((e - mv).abs() <= tol, "{tc:?} {t} °C: {e} mV, expected {mv}");
        };
        check(TcType::C, 1000.0, 18.2602, 0.00005);
        for (t, mv) in [(-190.0, -9.203), (200.0, 14.560), (400.0, 31.492), (600.0, 49.108), (800.0, 66.466)] {
            check(TcType::L, t, mv, 0.0005);
        }
        for (t, mv) in [(-150.0, -5.111), (-100.0, -3.715), (50.0, 2.252)] {
            check(TcType::M, t, mv, 0.0005);
        }
    }
}
