//! The result codes the module answers, shared by the discovery protocol's commands and the
//! firmware update session.

/// Result codes of the configuration commands (and of the update session).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Status {
    /// Done.
    Ok = 0,
    /// The proof does not match the module's password: nothing changed.
    WrongPassword = 1,
    /// The module-wide guessing budget is spent: not checked, try later.
    RateLimited = 2,
    /// The settings are not usable (mask, address, port, credential), or an image is not for
    /// this module.
    Invalid = 3,
    /// The settings (or the update) could not be stored.
    StoreFailed = 4,
    /// Firmware update only: the image's signature does not match its header and firmware, or
    /// was not made with this module's key. Nothing changed.
    BadSignature = 5,
    /// The nonce is not one the module handed out, was used already or expired: nothing was
    /// checked; ask for a new challenge.
    StaleNonce = 6,
    /// The factory password is still in force: set a password first (firmware updates and
    /// allow-list changes are refused until then).
    SetPasswordFirst = 7,
    /// Firmware update only: the image's security counter is below the module's (an older
    /// release, anti-rollback). Nothing changed.
    Downgrade = 8,
    /// Too many settings changes: the module's flash commit budget is spent (flash wear,
    /// one more change every 15 minutes). Nothing changed; try again later.
    CommitBudget = 9,
}

impl Status {
    /// The status of a code.
    pub fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            0 => Status::Ok,
            1 => Status::WrongPassword,
            2 => Status::RateLimited,
            3 => Status::Invalid,
            4 => Status::StoreFailed,
            5 => Status::BadSignature,
            6 => Status::StaleNonce,
            7 => Status::SetPasswordFirst,
            8 => Status::Downgrade,
            9 => Status::CommitBudget,
            _ => return None,
        })
    }

    /// Whether the module answers this status only after a right proof: such an answer
    /// carries the module's signature.
    pub fn after_proof(self) -> bool {
        !matches!(self, Status::WrongPassword | Status::RateLimited | Status::StaleNonce)
    }
}
