//! One acquisition cycle's published values: what the cycle hands the register map.

use remodaq_protocol::m8318::{ChannelStatus, CHANNELS};

/// One cycle's published values.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Snapshot {
    /// Registers 40001-40008.
    pub values: [u16; CHANNELS],
    /// Registers 40225-40232: why each value reads what it reads.
    pub status: [ChannelStatus; CHANNELS],
    /// Register 40009: corrected CJC temperature, 0.01 °C.
    pub cjc: i16,
    /// A conversion of this cycle failed (the front end did not answer, or timed out).
    pub front_end_fault: bool,
    /// The cold-junction sensor could not be read this cycle.
    pub cjc_fault: bool,
}

impl Default for Snapshot {
    fn default() -> Self {
        Self {
            values: [0; CHANNELS],
            status: [ChannelStatus::Ok; CHANNELS],
            cjc: 0,
            front_end_fault: false,
            cjc_fault: false,
        }
    }
}
