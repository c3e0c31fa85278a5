//! The Modbus exception codes the modules answer with (spec §1.2).

/// Modbus exception codes used by the modules (spec §1.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Exception {
    /// 01: function code not supported.
    IllegalFunction = 1,
    /// 02: an address of the request is not mapped for that access.
    IllegalDataAddress = 2,
    /// 03: bad quantity, byte count, coil value or register value.
    IllegalDataValue = 3,
    /// 04: the operation failed (e.g. the settings store could not commit).
    ServerDeviceFailure = 4,
}
