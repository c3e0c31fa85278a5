//! The web console (issue #25, docs/web.md): its sessions ([`sessions`], plain logic) and, with
//! the feature `web`, its HTTP service on picoserve ([`service`]).

#[cfg(feature = "web")]
pub mod firmware;
#[cfg(feature = "web")]
pub mod json;
#[cfg(feature = "web")]
pub mod service;
pub mod sessions;
#[cfg(feature = "web")]
pub mod settings;

pub use sessions::*;
