//! Firmware update (TCP, port [`PORT`]): the signed image file and the session's wire format.
//! See `docs/update.md`.
//!
//! An image file is a [`Header`] then the firmware bytes. The signature is ed25519 over the
//! SHA-512 digest of the firmware bytes (what `embassy-boot` verifies before it marks the
//! update). A session: the PC sends the configuration password (one length byte, then the
//! bytes), then the image file; the module answers one [`Status`] byte after the header (go on,
//! or why not) and one after the firmware bytes (verified and marked, or why not), then
//! restarts into the new image when the second is [`Status::Ok`].

/// The TCP port of the update service.
pub const PORT: u16 = 8301;
/// First bytes of an image file.
pub const MAGIC: [u8; 4] = *b"RDQU";
/// Image file format version.
pub const FORMAT: u8 = 1;
/// Bytes of an encoded [`Header`].
pub const HEADER_LEN: usize = 4 + 1 + 1 + 2 + 2 + 4 + 64;

/// The header of an image file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Module name register value the image is for (8318h, 8350h).
    pub model: u16,
    /// Firmware version of the image (register 40213).
    pub version: u16,
    /// Length of the firmware bytes that follow.
    pub length: u32,
    /// ed25519 signature of the SHA-512 digest of the firmware bytes.
    pub signature: [u8; 64],
}

impl Header {
    /// The encoded header.
    pub fn encode(&self) -> [u8; HEADER_LEN] {
        let mut out = [0u8; HEADER_LEN];
        out[..4].copy_from_slice(&MAGIC);
        out[4] = FORMAT;
        out[6..8].copy_from_slice(&self.model.to_be_bytes());
        out[8..10].copy_from_slice(&self.version.to_be_bytes());
        out[10..14].copy_from_slice(&self.length.to_be_bytes());
        out[14..].copy_from_slice(&self.signature);
        out
    }

    /// Decodes a header; `None` for another magic, format or a reserved byte not 0.
    pub fn decode(bytes: &[u8; HEADER_LEN]) -> Option<Self> {
        if bytes[..4] != MAGIC || bytes[4] != FORMAT || bytes[5] != 0 {
            return None;
        }
        let mut signature = [0u8; 64];
        signature.copy_from_slice(&bytes[14..]);
        Some(Self {
            model: u16::from_be_bytes([bytes[6], bytes[7]]),
            version: u16::from_be_bytes([bytes[8], bytes[9]]),
            length: u32::from_be_bytes([bytes[10], bytes[11], bytes[12], bytes[13]]),
            signature,
        })
    }
}

/// The module's answers in a session: the status codes of the discovery protocol's commands
/// (0 ok, 1 wrong password, 2 rate limited, 3 not an image for this module, 4 the update
/// partition could not be written), and 5 for a signature that does not match.
pub use crate::discovery::Status;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trip() {
        let h = Header { model: 0x8350, version: 0xA101, length: 123_456, signature: [7; 64] };
        let bytes = h.encode();
        assert_eq!(&bytes[..14], b"RDQU\x01\x00\x83\x50\xA1\x01\x00\x01\xE2\x40");
        assert_eq!(Header::decode(&bytes), Some(h));
        let mut bad = bytes;
        bad[4] = 2;
        assert_eq!(Header::decode(&bad), None);
        assert_eq!(Status::from_code(5), Some(Status::BadSignature));
    }
}
