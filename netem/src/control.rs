//! The state the [`Netem`](crate::Netem) handle, the HTTP API and the link tasks share, and
//! runtime control over it (docs/design.md §5): the links by pair, the step with the robots'
//! poses and the scheduled faults, and applying a fault — cut, partition, reset, toxics — to the
//! links it names. Below both the handle (`netem.rs`) and the HTTP API (`http.rs`), which each
//! act on links only through it.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex, MutexGuard};

use proto::clock::{SimClock, SimTime};
use proto::geom::Pose;
use proto::msg::{ProcessOrder, RobotId, Step};
use tokio::sync::{mpsc, watch};

use crate::accounting::Dir;
use crate::faults::{self, ActiveToxic, Fault, Pair, ScheduledFault, Toxic, ToxicKind};
use crate::link::{Link, LinkSnapshot, MAX_TOXICS};
use crate::radio::Radio;
use crate::shaping::Budget;
use crate::telemetry::{telemetry_row, LinkTelemetry};

/// Why netem did not start, or refused a fault.
#[derive(Debug, thiserror::Error)]
pub enum NetemError {
    #[error("invalid netem configuration: {0}")]
    Config(String),
    #[error("cannot listen on {addr} for {what}: {source}")]
    Bind {
        what: String,
        addr: SocketAddr,
        source: std::io::Error,
    },
    #[error("no link {0} (links are named r<a>-r<b>)")]
    UnknownLink(String),
    #[error("robot {0} is in no link")]
    UnknownRobot(RobotId),
    #[error("link {link} has no toxic {name}")]
    UnknownToxic { link: String, name: String },
    #[error("toxic {name} already exists on link {link}")]
    ToxicExists { link: String, name: String },
    #[error("invalid toxic: {0}")]
    InvalidToxic(String),
    #[error("link {0} already has the most toxics allowed ({MAX_TOXICS})")]
    TooManyToxics(String),
    #[error("faults[{index}]: {reason}")]
    BadFault { index: usize, reason: String },
}

/// The state shared by the handle, the HTTP API and the tasks.
pub(crate) struct Shared {
    pub(crate) clock: SimClock,
    pub(crate) links: Vec<Arc<Link>>,
    /// The index in `links` of each pair (lower id first).
    pub(crate) by_pair: HashMap<Pair, usize>,
    pub(crate) radio: Radio,
    /// How far apart two nodes may be for their pair to have a row in a step's report though
    /// its link is down (`None`: any distance, the `always` model). See `reported`.
    pub(crate) report_within_m: Option<f64>,
    /// `airtime`: the radio whose range is the interference range (`None`: the links' own).
    pub(crate) interference: Option<Radio>,
    /// The shared channel and lost frames, step by step (lockstep with markers).
    pub(crate) channel: Mutex<crate::channel::Channel>,
    /// Each node's use of the channel in the last step closed.
    pub(crate) nodes_air: Mutex<Vec<proto::msg::NodeAir>>,
    pub(crate) step_seconds: f64,
    /// See `NetemConfig::markers`.
    pub(crate) markers: bool,
    pub(crate) steps: Mutex<StepState>,
    pub(crate) toxic_ids: AtomicU64,
    pub(crate) shutdown: watch::Sender<bool>,
    /// See [`NetemConfig::api_token`](crate::NetemConfig::api_token).
    pub(crate) api_token: Option<String>,
    /// Where the API's process faults go, once
    /// [`Netem::process_orders`](crate::Netem::process_orders) was called.
    pub(crate) process_desk: Mutex<Option<ProcessDesk>>,
}

/// The API's process faults: checked against the run's scenario, queued for the sim plane.
pub(crate) struct ProcessDesk {
    pub(crate) scenario: proto::scenario::Scenario,
    pub(crate) orders: mpsc::Sender<ProcessOrder>,
}

/// Process faults the API holds for the sim plane at most (more are refused with 503).
pub(crate) const PROCESS_ORDERS_QUEUED: usize = 64;

/// The last step, the robots' last poses (and liveness), and the scheduled faults.
pub(crate) struct StepState {
    pub(crate) step: Option<Step>,
    pub(crate) poses: HashMap<RobotId, (Pose, bool)>,
    /// Sorted by step; `next` is the first not yet applied.
    pub(crate) faults: Vec<ScheduledFault>,
    pub(crate) next: usize,
}

/// Locks `m`, also when a thread panicked holding it (the state stays usable).
pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Lockstep: how many steps of a link's rate may cross at once. The robots pace what they offer
/// (bursts of a few steps, never more than the rate on average); netem lets a larger burst
/// through, so that a step's data and the step's marker behind them never wait for a later step
/// (which, with the clock standing still until every robot is done, would only end at the
/// world's step timeout). Over time the rate is still netem's to enforce.
pub const LOCKSTEP_BURST_STEPS: f64 = 12.0;
/// Lockstep: the smallest burst in bytes (a few zenoh frames around one large message).
pub const LOCKSTEP_BURST_MIN_BYTES: f64 = 4096.0;

/// The burst of a budget of `rate` bytes per second, in simulated seconds: one step (a link never
/// saves up more), or [`LOCKSTEP_BURST_STEPS`] steps with step markers.
pub(crate) fn burst_seconds(rate: u64, step_seconds: f64, markers: bool) -> f64 {
    if markers {
        (step_seconds * LOCKSTEP_BURST_STEPS).max(LOCKSTEP_BURST_MIN_BYTES / rate.max(1) as f64)
    } else {
        step_seconds
    }
}

impl Shared {
    /// The link of `pair` (either order).
    pub(crate) fn link(&self, pair: Pair) -> Result<&Arc<Link>, NetemError> {
        let key = (pair.0.min(pair.1), pair.0.max(pair.1));
        self.by_pair
            .get(&key)
            .map(|&i| &self.links[i])
            .ok_or_else(|| NetemError::UnknownLink(faults::link_name(pair.0, pair.1)))
    }

    /// The link named `r<a>-r<b>`.
    pub(crate) fn link_by_name(&self, name: &str) -> Result<&Arc<Link>, NetemError> {
        faults::parse_link_name(name)
            .and_then(|p| self.by_pair.get(&p))
            .map(|&i| &self.links[i])
            .ok_or_else(|| NetemError::UnknownLink(name.to_string()))
    }

    /// The link of `pair`, or every link for `None`.
    fn links_of(&self, pair: Option<Pair>) -> Result<Vec<&Arc<Link>>, NetemError> {
        match pair {
            Some(p) => Ok(vec![self.link(p)?]),
            None => Ok(self.links.iter().collect()),
        }
    }

    /// The last step given to the handle (`None` before the first).
    pub(crate) fn step(&self) -> Option<Step> {
        lock(&self.steps).step
    }

    /// A toxic made active: its id, and its own budgets if it limits bandwidth.
    fn install(&self, toxic: &Toxic) -> ActiveToxic {
        let budget = |d: Dir| match toxic.kind {
            ToxicKind::Bandwidth { rate_bytes_per_s }
                if rate_bytes_per_s > 0 && toxic.stream.applies(d) =>
            {
                Some(Budget::new(
                    rate_bytes_per_s,
                    burst_seconds(rate_bytes_per_s, self.step_seconds, self.markers),
                    false,
                    self.clock.clone(),
                ))
            }
            _ => None,
        };
        ActiveToxic {
            toxic: toxic.clone(),
            id: self.toxic_ids.fetch_add(1, Relaxed),
            budgets: Dir::BOTH.map(budget),
        }
    }

    /// Adds (or with `replace`, adds or replaces) a toxic on one link.
    fn put_toxic(&self, link: &Link, toxic: &Toxic, replace: bool) -> Result<(), NetemError> {
        let mut list: Vec<ActiveToxic> = link.toxics().as_ref().clone();
        match list.iter().position(|t| t.toxic.name == toxic.name) {
            Some(_) if !replace => {
                return Err(NetemError::ToxicExists {
                    link: link.name.clone(),
                    name: toxic.name.clone(),
                })
            }
            Some(i) => list[i] = self.install(toxic),
            None if list.len() >= MAX_TOXICS => {
                return Err(NetemError::TooManyToxics(link.name.clone()))
            }
            None => list.push(self.install(toxic)),
        }
        link.set_toxics(list);
        Ok(())
    }

    /// Applies `fault` now to the links it names.
    pub(crate) fn apply(&self, fault: &Fault) -> Result<(), NetemError> {
        tracing::info!(?fault, "applying fault");
        match fault {
            Fault::Cut { pair } => {
                self.link(*pair)?.update(|s| s.enabled = false);
            }
            Fault::Restore { pair } => {
                self.link(*pair)?.update(|s| s.enabled = true);
            }
            Fault::Partition { groups } => self.partition(groups)?,
            Fault::Heal => {
                for l in &self.links {
                    l.update(|s| s.enabled = true);
                }
            }
            Fault::Reset { pair } => {
                for l in self.links_of(*pair)? {
                    l.reset_connections();
                }
            }
            Fault::AddToxic { pair, toxic } => self.add_toxic(*pair, toxic, false)?,
            Fault::SetToxic { pair, toxic } => self.add_toxic(*pair, toxic, true)?,
            Fault::RemoveToxic { pair, name } => self.remove_toxic(*pair, name)?,
            Fault::ResetAll => {
                for l in &self.links {
                    l.set_toxics(Vec::new());
                    l.update(|s| s.enabled = true);
                }
            }
        }
        Ok(())
    }

    /// Cuts every link whose robots are in different `groups` (each robot named must be in one).
    fn partition(&self, groups: &[Vec<RobotId>]) -> Result<(), NetemError> {
        let mut group_of = HashMap::new();
        for (g, members) in groups.iter().enumerate() {
            for r in members {
                if !self
                    .links
                    .iter()
                    .any(|l| l.params.a == *r || l.params.b == *r)
                {
                    return Err(NetemError::UnknownRobot(*r));
                }
                group_of.insert(*r, g);
            }
        }
        for l in &self.links {
            if let (Some(ga), Some(gb)) = (group_of.get(&l.params.a), group_of.get(&l.params.b)) {
                if ga != gb {
                    l.update(|s| s.enabled = false);
                }
            }
        }
        Ok(())
    }

    /// Adds (or with `replace`, adds or replaces) `toxic` on the link of `pair` (`None`: all).
    fn add_toxic(
        &self,
        pair: Option<Pair>,
        toxic: &Toxic,
        replace: bool,
    ) -> Result<(), NetemError> {
        let links = self.links_of(pair)?;
        if !replace {
            for l in &links {
                if l.toxics().iter().any(|t| t.toxic.name == toxic.name) {
                    return Err(NetemError::ToxicExists {
                        link: l.name.clone(),
                        name: toxic.name.clone(),
                    });
                }
            }
        }
        for l in links {
            self.put_toxic(l, toxic, replace)?;
        }
        Ok(())
    }

    /// Removes the toxic `name` from the link of `pair` (`None`: all); an error if none had it.
    fn remove_toxic(&self, pair: Option<Pair>, name: &str) -> Result<(), NetemError> {
        let links = self.links_of(pair)?;
        let mut found = false;
        for l in &links {
            let list = l.toxics();
            if list.iter().any(|t| t.toxic.name == name) {
                found = true;
                l.set_toxics(
                    list.iter()
                        .filter(|t| t.toxic.name != name)
                        .cloned()
                        .collect(),
                );
            }
        }
        if !found {
            return Err(NetemError::UnknownToxic {
                link: pair.map_or_else(|| "(any)".into(), |p| faults::link_name(p.0, p.1)),
                name: name.to_string(),
            });
        }
        Ok(())
    }

    /// Every link's snapshot, in the order of the pairs.
    pub(crate) fn snapshots(&self) -> Vec<LinkSnapshot> {
        self.links.iter().map(|l| l.snapshot()).collect()
    }

    /// Every link's snapshot with every port its proxy listened on (`link_totals.csv`).
    pub(crate) fn totals(&self) -> Vec<(LinkSnapshot, Vec<u16>)> {
        self.links
            .iter()
            .map(|l| (l.snapshot(), l.ports()))
            .collect()
    }

    /// The simulated time now.
    pub(crate) fn now(&self) -> SimTime {
        self.clock.now()
    }

    /// The telemetry rows without resetting the per-step counters (their byte fields read 0).
    pub(crate) fn rows(&self) -> Vec<LinkTelemetry> {
        let step = self.step();
        self.snapshots()
            .iter()
            .map(|s| telemetry_row(step, s, [0, 0]))
            .collect()
    }
}
