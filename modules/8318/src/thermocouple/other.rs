//! Reference functions of the types NIST does not cover, from `shared/reference/README.md`:
//! C (W-5%Re / W-26%Re, ASTM E230 / IEC 60584-1:2013), L (chromel-copel) and M (copper-copel)
//! (GOST R 8.585-2001). E = sum c_i t^i (mV, °C). The L constants are not zero (E(0) = -1.9e-5
//! mV): kept as published.

use super::piece::Piece;

/// Type C subranges.
pub const C: &[Piece] = &[
    Piece {
        lo: 0.0,
        hi: 630.615,
        c: &[0.0, 1.3406032e-2, 1.1924992e-5, -7.9806354e-9, -5.0787515e-12, 1.3164197e-14, -7.9197332e-18],
    },
    Piece {
        lo: 630.615,
        hi: 2315.0,
        c: &[4.0528823e-1, 1.1509355e-2, 1.5696453e-5, -1.3704412e-8, 5.2290873e-12, -9.2082758e-16, 4.5245112e-20],
    },
];

/// Type L subranges.
pub const L: &[Piece] = &[
    Piece {
        lo: -200.0,
        hi: 0.0,
        c: &[
            -5.8952244e-5,
            6.3391502e-2,
            6.7592964e-5,
            2.0672566e-7,
            5.5720884e-9,
            5.7133860e-11,
            3.2995593e-13,
            9.9232420e-16,
            1.2079584e-18,
        ],
    },
    Piece {
        lo: 0.0,
        hi: 800.0,
        c: &[
            -1.8656953e-5,
            6.3310975e-2,
            6.0153091e-5,
            -8.0073134e-8,
            9.6946071e-11,
            -3.6047289e-14,
            -2.4694775e-16,
            4.2880341e-19,
            -2.0725297e-22,
        ],
    },
];

/// Type M (one range).
pub const M: &[Piece] =
    &[Piece { lo: -200.0, hi: 100.0, c: &[2.4455560e-6, 4.2638917e-2, 5.0348392e-5, -4.4974485e-8] }];
