//! Identity registers common to both modules (spec §2.1, §3.2).

/// 40211: module name (8318h / 8350h).
pub const REG_NAME: u16 = 0x00D2;
/// 40213: firmware version.
pub const REG_VERSION: u16 = 0x00D4;
/// Firmware version reported in 40213.
pub const FIRMWARE_VERSION: u16 = 0xA100;

/// The value of an identity register of module `name`, if `addr` is one.
pub fn read(name: u16, addr: u16) -> Option<u16> {
    match addr {
        REG_NAME => Some(name),
        REG_VERSION => Some(FIRMWARE_VERSION),
        _ => None,
    }
}
