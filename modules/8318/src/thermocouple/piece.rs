//! The subrange of a reference function, the unit the coefficient tables are written in.

/// One subrange of a reference function: E(t) = sum c_i t^i for lo <= t <= hi.
pub struct Piece {
    /// Lowest temperature of the subrange, °C.
    pub lo: f64,
    /// Highest temperature of the subrange, °C.
    pub hi: f64,
    /// Coefficients, mV / °C^i, constant term first.
    pub c: &'static [f64],
}
