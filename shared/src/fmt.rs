//! One logging shim for the whole firmware: `defmt` on the target, `log` on the host, nothing
//! when neither feature is on (the pattern of Embassy's `fmt.rs`). The backend is chosen by this
//! crate's features at the macro's definition, so every crate of the workspace logs through
//! `remodaq_shared::{info, warn, ...}` with the same call sites. Format strings must suit both
//! backends: plain `{}` / `{:?}` placeholders only.

#[cfg(all(feature = "defmt", feature = "log"))]
compile_error!("features `defmt` and `log` are mutually exclusive");

#[cfg(feature = "defmt")]
#[doc(hidden)]
pub use defmt as __backend;
#[cfg(feature = "log")]
#[doc(hidden)]
pub use log as __backend;

#[cfg(any(feature = "defmt", feature = "log"))]
#[doc(hidden)]
#[macro_export]
macro_rules! __log {
    ($level:ident, $($arg:tt)*) => { $crate::fmt::__backend::$level!($($arg)*) };
}

#[cfg(not(any(feature = "defmt", feature = "log")))]
#[doc(hidden)]
#[macro_export]
macro_rules! __log {
    ($level:ident, $fmt:literal $(, $arg:expr)* $(,)?) => {{ $( let _ = &$arg; )* }};
}

/// Log at trace level.
#[macro_export]
macro_rules! trace { ($($arg:tt)*) => { $crate::__log!(trace, $($arg)*) }; }
/// Log at debug level.
#[macro_export]
macro_rules! debug { ($($arg:tt)*) => { $crate::__log!(debug, $($arg)*) }; }
/// Log at info level.
#[macro_export]
macro_rules! info { ($($arg:tt)*) => { $crate::__log!(info, $($arg)*) }; }
/// Log at warn level.
#[macro_export]
macro_rules! warn { ($($arg:tt)*) => { $crate::__log!(warn, $($arg)*) }; }
/// Log at error level.
#[macro_export]
macro_rules! error { ($($arg:tt)*) => { $crate::__log!(error, $($arg)*) }; }

/// What a value needs to be logged with `{:?}` by every backend: `Debug`, and on the target
/// `defmt::Format`. Use it as the bound of generic error types that are logged.
#[cfg(feature = "defmt")]
pub trait Loggable: core::fmt::Debug + defmt::Format {}
#[cfg(feature = "defmt")]
impl<T: core::fmt::Debug + defmt::Format + ?Sized> Loggable for T {}

/// What a value needs to be logged with `{:?}` by every backend (here: `Debug`).
#[cfg(not(feature = "defmt"))]
pub trait Loggable: core::fmt::Debug {}
#[cfg(not(feature = "defmt"))]
impl<T: core::fmt::Debug + ?Sized> Loggable for T {}

/// Logs any `Debug` value with `{:?}` on every backend (on the target through
/// `defmt::Debug2Format`, which costs flash: use it for rare errors only).
pub struct Debug<'a, T: core::fmt::Debug + ?Sized>(pub &'a T);

impl<T: core::fmt::Debug + ?Sized> core::fmt::Debug for Debug<'_, T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        self.0.fmt(f)
    }
}

#[cfg(feature = "defmt")]
impl<T: core::fmt::Debug + ?Sized> defmt::Format for Debug<'_, T> {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "{}", defmt::Debug2Format(self.0))
    }
}
