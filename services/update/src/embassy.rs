//! The update service on an embassy-net socket (the STM32 and QEMU boards): one session at a
//! time on TCP port 8301, and, between two sessions, the web console's upload steps (feature
//! `web`).

use embassy_net::tcp::TcpSocket;
use embassy_time::Instant;
#[cfg(feature = "web")]
use embassy_time::Timer;
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_net::{accept_one, close, peer, reset, EmbassyNet};
use remodaq_shared::board::{Effects, Network as _, Shared};
use remodaq_shared::module::{SettingsAccess, Store};

use remodaq_protocol::update::PORT;

use crate::session::{Outcome, UpdateService};
use crate::target::UpdateTarget;

/// The update task of an embassy-net board: confirms the running image ([`crate::start`]), then
/// serves update sessions forever; restarts the module after an image was verified and marked.
#[allow(clippy::too_many_arguments)]
pub async fn serve<E, A, F, DFU, STATE>(
    net: &'static EmbassyNet<E>,
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    model: u16,
    mac: [u8; 6],
    dfu: DFU,
    state: STATE,
) -> !
where
    E: Effects,
    A: SettingsAccess,
    F: NorFlash,
    DFU: NorFlash,
    STATE: NorFlash,
{
    let mut aligned = [0u8; 32];
    let (mut target, mut service) = crate::trial::start(net, map, store, model, mac, dfu, state, &mut aligned).await;
    serve_sessions(net, map, store, &mut service, &mut target).await
}

/// Serves firmware update sessions into `target`, one at a time, forever; restarts the module
/// after an image was verified and marked.
pub async fn serve_sessions<E: Effects, A: SettingsAccess, F: NorFlash, U: UpdateTarget>(
    net: &'static EmbassyNet<E>,
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    service: &mut UpdateService,
    target: &mut U,
) -> ! {
    // Bounded: one session at a time, through these buffers and the service's 1 KiB chunk.
    let mut rx = [0u8; 2048];
    let mut tx = [0u8; 64];
    loop {
        let mut socket = TcpSocket::new(net.stack, &mut rx, &mut tx);
        // The web console's steps are taken between two sessions.
        #[cfg(feature = "web")]
        let accepted = {
            use remodaq_shared::upload::{WebDone, WEB};
            let accepting = accept_one(&mut socket, PORT, "update");
            match embassy_futures::select::select(accepting, WEB.next()).await {
                embassy_futures::select::Either::First(accepted) => accepted,
                embassy_futures::select::Either::Second((number, step)) => {
                    let done = service.web_step(&step, map, store, target).await;
                    let updated = matches!(done, Ok(WebDone::Updated(_)));
                    WEB.answer(number, done);
                    // The console's connection restarts the module once it answered; if it
                    // cannot, this does, a little later.
                    if updated {
                        Timer::after(embassy_time::Duration::from_secs(3)).await;
                        net.restart().await;
                    }
                    continue;
                }
            }
        };
        #[cfg(not(feature = "web"))]
        let accepted = accept_one(&mut socket, PORT, "update").await;
        if !accepted {
            continue;
        }
        let now_ms = Instant::now().as_millis();
        let from = peer(&socket);
        let outcome = service.session(&mut socket, from, now_ms, map, store, target).await;
        close(&mut socket).await;
        reset(&mut socket).await;
        if let Outcome::Updated { .. } = outcome {
            net.restart().await;
        }
    }
}
