//! RemoDAQ-8300 Utility: the window of the manuals' chapter 3 (a tree of the modules found,
//! their network settings, live panels, trends, diagnostics, security and firmware update),
//! on the same client library as the `remodaq` CLI.

pub mod app;
pub mod fonts;
pub mod i18n;
pub mod trend;
pub mod validate;
pub mod worker;

pub use app::{Options, Utility};
