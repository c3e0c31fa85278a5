//! What went wrong, in the classes the CLI's exit codes and the utility's messages use.

/// What went wrong, with the exit code it gives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Error {
    /// No answer in time (exit 3).
    Timeout(String),
    /// The module answered a Modbus exception (exit 4).
    Exception(String),
    /// Wrong password or rate limited (exit 5).
    Refused(String),
    /// The peer's reply does not fit the request: short, long, another function or
    /// transaction, or not Modbus at all (exit 6). Not a RemoDAQ module, or a broken one.
    Reply(String),
    /// Anything else: connection, bad argument, unexpected answer (exit 1).
    Other(String),
}

impl Error {
    /// The exit code of the CLI.
    pub fn code(&self) -> u8 {
        match self {
            Error::Other(_) => 1,
            Error::Timeout(_) => 3,
            Error::Exception(_) => 4,
            Error::Refused(_) => 5,
            Error::Reply(_) => 6,
        }
    }
}

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Error::Timeout(m) => write!(f, "timeout: {m}"),
            Error::Reply(m) => write!(f, "bad reply: {m}"),
            Error::Exception(m) | Error::Refused(m) | Error::Other(m) => f.write_str(m),
        }
    }
}
