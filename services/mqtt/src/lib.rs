//! MQTT (issue #40, docs/mqtt.md): what a module publishes and the commands the 8350 takes, as
//! plain `no_std` logic tested on the host: the topics ([`topics`]), when a point is published
//! ([`schedule`]), and an output command's Modbus writes ([`command`]). The client session
//! (minimq, over embedded-tls: [`session`]) is built on these, and the service every board runs
//! ([`service`]) on the session, over the board's connection to the broker (`embassy` on the
//! embassy-net boards).
#![no_std]
#![warn(missing_docs)]

#[cfg(any(test, feature = "testing"))]
extern crate std;

#[cfg(feature = "tls")]
pub mod certificate;
pub mod command;
#[cfg(feature = "embassy-net")]
pub mod embassy;
#[cfg(feature = "embassy-net")]
pub mod link;
/// MQTT's settings: the record and its checks, in the runtime (`remodaq_shared::mqtt`), which
/// the services that set them share.
pub mod config {
    pub use remodaq_shared::mqtt::*;
}
pub mod points;
#[cfg(feature = "tls")]
pub mod records;
pub mod schedule;
pub mod service;
pub mod session;
#[cfg(feature = "embassy-net")]
pub mod sntp;
#[cfg(feature = "testing")]
pub mod testing;
#[cfg(feature = "tls")]
pub mod tls;
pub mod topics;
