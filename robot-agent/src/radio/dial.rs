//! Opening a robot's radio sessions as links come up: a robot connects to netem's proxy of each
//! pair in which it has the lower id when a step's plan gives the proxy's address
//! ([`PlannedLink::proxy`](proto::msg::PlannedLink::proxy)) — netem listens for a pair only while
//! its link is up, so a team's radio costs descriptors and sessions for the pairs in range, not for
//! every pair (docs/design.md §1.1).
//!
//! zenoh's configuration fixes the endpoints a session connects to when it opens; a connection
//! opened later goes through its runtime (`Runtime::connect_peer`, zenoh's `internal` API),
//! which opens a transport to the peer's zenoh id over the locator given.

use std::collections::HashMap;
use std::net::SocketAddr;

use proto::msg::{LinkPlan, RobotId};
use proto::node::{radio_zid, zerr, ZenohError};
use tokio::task::JoinHandle;
use zenoh::config::{Config, Locator, ZenohId};
use zenoh::internal::runtime::{Runtime, RuntimeBuilder};
use zenoh::Session;

/// A robot's radio plane: its zenoh session and the runtime under it, through which it opens
/// sessions as links come up.
pub struct RadioPlane {
    pub session: Session,
    runtime: Runtime,
}

impl RadioPlane {
    /// Opens the radio plane of `config` (the session, then its runtime started, as
    /// `zenoh::open` does).
    pub async fn open(config: Config) -> Result<RadioPlane, ZenohError> {
        let mut runtime = RuntimeBuilder::new(config).build().await.map_err(zerr)?;
        let session = zenoh::session::init(runtime.clone().into())
            .await
            .map_err(zerr)?;
        runtime.start().await.map_err(zerr)?;
        Ok(RadioPlane { session, runtime })
    }

    /// A dialer of this plane's sessions.
    pub fn dialer(&self, me: RobotId) -> Dialer {
        Dialer {
            runtime: self.runtime.clone(),
            me,
            dialing: HashMap::new(),
        }
    }

    /// Closes the session and the runtime (a session made on a runtime does not close it),
    /// within a second each.
    pub async fn close(self) {
        proto::node::close_quickly(self.session).await;
        let close = async move { self.runtime.close().await };
        if let Ok(Err(e)) = tokio::time::timeout(std::time::Duration::from_secs(1), close).await {
            tracing::debug!("closing the radio runtime: {e}");
        }
    }
}

/// Opens a robot's sessions to the proxies its steps' plans give.
pub struct Dialer {
    runtime: Runtime,
    me: RobotId,
    /// The sessions being opened: to whom, through which proxy.
    dialing: HashMap<RobotId, (SocketAddr, JoinHandle<()>)>,
}

impl Dialer {
    /// Opens a session through each proxy `plan` gives this robot (the links in which it has
    /// the lower id), unless `up` says the session is there or one is being opened through that
    /// proxy already. An attempt that failed is made again at the next call.
    pub fn dial(&mut self, plan: &LinkPlan, up: impl Fn(RobotId) -> bool) {
        self.dialing.retain(|_, (_, task)| !task.is_finished());
        for l in plan.links.iter().filter(|l| l.a == self.me) {
            let Some(proxy) = l.proxy else { continue };
            if up(l.b) || self.dialing.get(&l.b).is_some_and(|(at, _)| *at == proxy) {
                continue;
            }
            let (Ok(zid), Ok(locator)) = (
                radio_zid(l.b).parse::<ZenohId>(),
                format!("tcp/{proxy}").parse::<Locator>(),
            ) else {
                continue;
            };
            let runtime = self.runtime.clone();
            let task = tokio::spawn(async move {
                if !runtime.connect_peer(&zid.into(), &[locator]).await {
                    tracing::debug!("no session to {zid} through {proxy} yet");
                }
            });
            self.dialing.insert(l.b, (proxy, task));
        }
    }
}
