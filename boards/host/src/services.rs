//! The network services over the host board's std sockets: one function per service, with the
//! same shape as each service's embassy-net transport (`remodaq_modbus::embassy::serve`, ...), so
//! that the image (boards/image.rs) runs either by name. The services' logic is theirs; this is
//! only the accepting and the sockets (modbus.rs, discovery.rs, web.rs).

use embedded_storage_async::nor_flash::NorFlash;
use remodaq_modbus::ModbusSlots;
use remodaq_shared::board::{Network as _, Shared};
use remodaq_shared::identity::Identity;
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::{SettingsAccess, Store};

use crate::HostNet;

/// Accepts and serves Modbus/TCP connections in `slot`, forever.
pub async fn modbus<M: RegisterMap>(
    net: &'static HostNet,
    map: &'static Shared<M>,
    slots: &'static ModbusSlots,
    slot: usize,
) -> ! {
    crate::modbus::connection_task(&net.listener, map, slots, slot).await
}

/// Serves the discovery and configuration protocol, forever.
pub async fn discovery<A: SettingsAccess, F: NorFlash>(
    net: &'static HostNet,
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    identity: Identity,
) -> ! {
    crate::discovery::run(&net.discovery, map, store, identity, &crate::discovery::HostEffects).await
}

/// Serves web console connections (`--http`), forever; restarts the module when a signed request
/// asked for it. Without `--http`, waits for ever.
pub async fn web<A: RegisterMap + SettingsAccess, F: NorFlash>(
    net: &'static HostNet,
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    identity: Identity,
) -> ! {
    match &net.web {
        Some(listener) => {
            crate::web::connection_task(listener, map, store, identity).await;
            net.restart().await
        }
        None => core::future::pending().await,
    }
}

/// MQTT with the stored settings (docs/mqtt.md), or to the broker of `--mqtt`, forever.
pub async fn mqtt<A: RegisterMap + SettingsAccess, F: NorFlash>(
    net: &'static HostNet,
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    identity: Identity,
) -> ! {
    crate::mqtt::run(net.mqtt, map, store, identity).await
}
