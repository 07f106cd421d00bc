//! The scenario schema: one TOML file (plus `--set KEY=VALUE` overrides) fully determines a run
//! together with its `seed` (docs/design.md §6). Every key is documented in `configs/default.toml`.
//!
//! Loading is two explicit steps (after ripgrep's config loading): the raw TOML table with
//! overrides applied is first checked key by key against the schema (unknown keys and wrong types
//! are named with their full dotted path), then deserialized and range-checked
//! ([`Scenario::validate`]). Every error is one line that names the key, the value and what is
//! allowed.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};

pub use crate::process::{Process, ProcessAction, ProcessKind, MAX_ROBOTS, PROCESS_FAULT_KINDS};

/// zenoh's own lease, which a sim-plane session keeps in realtime runs (wall milliseconds).
pub const SIM_LEASE_MS: u64 = 10_000;

/// Lockstep: a lease of an hour, so that no keep-alive is due while a run lasts (markers cross
/// every link every step). The cost: a peer that hangs without closing its connection is not
/// detected by the lease; one that exits or whose link netem cuts is, at once (the connection
/// closes).
pub const LOCKSTEP_RADIO_LEASE_MS: u64 = 3_600_000;

/// A whole run's configuration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Scenario {
    pub seed: u64,
    /// The run stops at this step at the latest; `None` (the key left out): derived from the
    /// map by [`Scenario::derived_max_steps`] when the scenario is resolved (`swarm run` writes
    /// the number into the run's `scenario.toml`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_steps: Option<u32>,
    pub done_pct: f64,
    pub clock: Clock,
    pub world: World,
    pub robots: Robots,
    pub sensor: Sensor,
    pub radio: Radio,
    pub exchange: Exchange,
    pub bandwidth: Bandwidth,
    pub coordination: Coordination,
    pub base_station: BaseStation,
    pub netem: Netem,
    pub supervise: Supervise,
    /// Faults applied when the run reaches a step: `[[faults]]` tables with `step`, `kind` and
    /// the kind's fields (see configs/default.toml). Link faults are parsed and checked by
    /// netem; process faults ([`PROCESS_FAULT_KINDS`]) by [`Scenario::process_faults`], carried
    /// out by the launcher.
    pub faults: Vec<toml::Table>,
}

/// `[supervise]`: which processes the launcher restarts when they die unexpectedly (a crash, or
/// a signal from outside the run), how soon and how often.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Supervise {
    /// Kinds of process restarted: `robot`, `netem`, `base-station` (the world-server is the
    /// simulation itself: its loss ends the run).
    pub restart: Vec<ProcessKind>,
    /// Steps of the world's clock between the death and the restart (0: at once).
    pub delay_steps: u32,
    /// Most restarts of one process in a run.
    pub max_restarts: u16,
}

impl Default for Supervise {
    fn default() -> Self {
        Supervise {
            restart: vec![ProcessKind::Robot, ProcessKind::Netem],
            delay_steps: 1,
            max_restarts: 3,
        }
    }
}

/// A process fault at a step.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ProcessFault {
    pub step: u32,
    #[serde(flatten)]
    pub action: ProcessAction,
}

/// Whether a `[[faults]]` table is a process fault (else a link fault).
pub fn is_process_fault(t: &toml::Table) -> bool {
    t.get("kind")
        .and_then(toml::Value::as_str)
        .is_some_and(|k| PROCESS_FAULT_KINDS.contains(&k))
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Clock {
    pub mode: ClockMode,
    /// Lockstep: robots act on radio traffic only at step boundaries (step markers, a barrier;
    /// robot-agent's `lockstep` module), so that a run is a function of its scenario. On by
    /// default; off, robots take radio traffic as it arrives (faster, not reproducible).
    pub markers: bool,
    pub step_seconds: f64,
    pub step_timeout_ms: u64,
    pub dead_after: u32,
    pub speedup: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ClockMode {
    Lockstep,
    Realtime,
}

impl Clock {
    /// Whether robots follow the step protocol with markers (lockstep with `markers = true`).
    pub fn marked(&self) -> bool {
        self.mode == ClockMode::Lockstep && self.markers
    }

    /// The `[clock]` part of [`Scenario::validate`].
    pub fn validate(&self) -> Result<(), ScenarioError> {
        positive("clock.step_seconds", self.step_seconds)?;
        positive("clock.speedup", self.speedup)?;
        at_least("clock.step_timeout_ms", self.step_timeout_ms as f64, 1.0)?;
        at_least("clock.dead_after", f64::from(self.dead_after), 1.0)
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct World {
    pub map: String,
    pub resolution_m: f64,
    pub width_m: f64,
    pub height_m: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Robots {
    pub count: u16,
    pub speed_m_per_s: f64,
    pub radius_m: f64,
    pub spawn_spacing_m: f64,
    pub spawn_clearance_m: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Sensor {
    pub beams: u32,
    pub fov_deg: f64,
    pub max_range_m: f64,
    pub noise_std_m: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Radio {
    pub model: RadioModel,
    pub range_m: f64,
    /// The range as a percentage of the environment's diagonal (the thesis's axis, §6.2). `swarm
    /// run` resolves it into `range_m` before it starts any process; processes started by hand
    /// use `range_m`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub range_pct_of_diagonal: Option<f64>,
    pub bandwidth_bytes_per_s: u64,
    pub medium: Medium,
    pub latency_ms: f64,
    pub jitter_ms: f64,
    pub pathloss_ref_dbm: f64,
    pub pathloss_ref_distance_m: f64,
    pub pathloss_exponent: f64,
    pub pathloss_wall_attenuation_db: f64,
    pub pathloss_max_walls: u32,
    /// `None`: the threshold at which the free-space range is `range_m`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pathloss_threshold_dbm: Option<f64>,
    /// `airtime`: how far a sender's transmission occupies the channel (its carrier-sense
    /// range), in metres, by the same model as the links (`pathloss`: the free-space range of
    /// the threshold it gives, walls shorten it); `None`: exactly the nodes it can talk to.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub interference_range_m: Option<f64>,
    /// The probability that a step's frame on a link is lost once (and sent again a step
    /// later), whatever the signal, in [0, 1).
    pub frame_loss: f64,
    /// `pathloss`: σ of the log-normal shadowing, dB: each robot pair's signal is off the
    /// model's by a fixed draw from N(0, σ²) (seeded by the scenario's seed and the pair).
    pub shadowing_db: f64,
    /// `pathloss`: σ of the fading around the (shadowed) signal in each step, dB: a frame is
    /// delivered with probability Φ(margin / σ), the margin being the signal above the
    /// threshold; 0: no fading.
    pub fading_db: f64,
}

/// netem's own knobs (the link emulator's process, not the radio it emulates).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Netem {
    pub buffer_bytes: u32,
    pub connect_timeout_ms: u64,
    /// Guard the HTTP API with a bearer token (`swarm run` makes one per run: `netem.token`).
    pub api_token: bool,
}

/// The longest latency, jitter or injected delay accepted anywhere (a day), in milliseconds.
pub const MAX_DELAY_MS: u64 = 24 * 3600 * 1000;

impl Radio {
    /// The `[radio]` part of [`Scenario::validate`], which netem applies to the radio it is
    /// given as well: one set of bounds.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        positive("radio.range_m", self.range_m)?;
        if let Some(p) = self.range_pct_of_diagonal {
            positive("radio.range_pct_of_diagonal", p)?;
        }
        for (key, v) in [
            ("radio.latency_ms", self.latency_ms),
            ("radio.jitter_ms", self.jitter_ms),
        ] {
            if !(v.is_finite() && (0.0..=MAX_DELAY_MS as f64).contains(&v)) {
                return Err(invalid(
                    key,
                    v,
                    &format!("must be in [0, {MAX_DELAY_MS}] ms"),
                ));
            }
        }
        positive(
            "radio.pathloss_ref_distance_m",
            self.pathloss_ref_distance_m,
        )?;
        positive("radio.pathloss_exponent", self.pathloss_exponent)?;
        at_least(
            "radio.pathloss_wall_attenuation_db",
            self.pathloss_wall_attenuation_db,
            0.0,
        )?;
        if !self.pathloss_ref_dbm.is_finite() {
            return Err(invalid(
                "radio.pathloss_ref_dbm",
                self.pathloss_ref_dbm,
                "must be a finite number",
            ));
        }
        if let Some(t) = self.pathloss_threshold_dbm.filter(|t| !t.is_finite()) {
            return Err(invalid(
                "radio.pathloss_threshold_dbm",
                t,
                "must be a finite number",
            ));
        }
        if let Some(r) = self.interference_range_m {
            positive("radio.interference_range_m", r)?;
        }
        if !(0.0..1.0).contains(&self.frame_loss) {
            return Err(invalid(
                "radio.frame_loss",
                self.frame_loss,
                "must be in [0, 1)",
            ));
        }
        for (key, v) in [
            ("radio.shadowing_db", self.shadowing_db),
            ("radio.fading_db", self.fading_db),
        ] {
            if !(v.is_finite() && (0.0..=40.0).contains(&v)) {
                return Err(invalid(key, v, "must be in [0, 40] dB"));
            }
            if v > 0.0 && self.model != RadioModel::Pathloss {
                return Err(invalid(key, v, "needs radio.model = \"pathloss\" (or 0)"));
            }
        }
        Ok(())
    }

    /// Whether frames can be lost (`frame_loss` or fading): netem draws a loss per link,
    /// direction and step.
    pub fn lossy(&self) -> bool {
        self.frame_loss > 0.0 || self.fading_db > 0.0
    }

    /// Whether netem allocates the channel's airtime step by step (`shared` and `airtime` in
    /// lockstep with markers, with a rate): its plan's credits are the senders' shares.
    pub fn allocates_airtime(&self, clock: &Clock) -> bool {
        clock.marked() && self.bandwidth_bytes_per_s > 0 && self.medium != Medium::PerLink
    }

    /// The bytes the shared channel carries in a step when netem allocates its airtime
    /// ([`Self::allocates_airtime`]): the rate over a step; `None` otherwise.
    pub fn channel_capacity(&self, clock: &Clock) -> Option<f64> {
        (self.allocates_airtime(clock))
            .then_some(self.bandwidth_bytes_per_s as f64 * clock.step_seconds)
    }
}

impl Netem {
    /// The `[netem]` part of [`Scenario::validate`] (netem applies it too).
    pub fn validate(&self) -> Result<(), ScenarioError> {
        at_least("netem.buffer_bytes", f64::from(self.buffer_bytes), 1024.0)?;
        at_least(
            "netem.connect_timeout_ms",
            self.connect_timeout_ms as f64,
            1.0,
        )
    }
}

impl Default for Netem {
    fn default() -> Self {
        Netem {
            buffer_bytes: 64 * 1024,
            connect_timeout_ms: 2000,
            api_token: false,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RadioModel {
    Disk,
    Pathloss,
    Always,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Medium {
    PerLink,
    Shared,
    Airtime,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Exchange {
    pub mode: ExchangeMode,
    pub hello_every_steps: u32,
    /// Polygon mode: every approximated edge carries its error bound and a receiver paints
    /// nothing free within it (docs/design.md §4.5); `false`: the thesis's exchange, edges
    /// without bounds, painted as they are.
    pub edge_bounds: bool,
    /// Polygon mode: a peer far behind on an owner's log gets the owner's approximation at a
    /// save point (a snapshot) instead of the history, when that is fewer ops (docs/design.md
    /// §4.4); `false`: the thesis's exchange, log suffixes only.
    pub snapshots: bool,
    /// How a log's records travel beyond its writer's neighbours (docs/design.md §4.4): `tree`,
    /// each robot takes each owner's records from one neighbour, the one nearest the owner's
    /// writer; `flood`, the thesis's Algorithm 8: every neighbour that holds records a peer
    /// lacks sends them.
    pub relay: Relay,
}

/// [`Exchange::relay`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Relay {
    Tree,
    Flood,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ExchangeMode {
    Polygon,
    RawScans,
    GridSnapshots,
}

/// How the polygon exchange's splitting frequency s follows the bandwidth (thesis §5.3;
/// docs/design.md §4.7).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Bandwidth {
    pub control: SplitControl,
    /// u, the desired medium usage rate of eq. 5.5.
    pub usage: f64,
    /// s of the `fixed` control, and where `adaptive` starts when the formula has no value.
    pub splits_per_step: f64,
    /// Bounds on s (the formula's value under unlimited bandwidth is the maximum).
    pub min_splits_per_step: f64,
    pub max_splits_per_step: f64,
    /// d before the robot has measured it: bytes of op log per split.
    pub split_bytes_prior: f64,
    /// p_comm of eq. 5.5; `None`: eq. 5.6 from the range and the map's extent.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub p_comm: Option<f64>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SplitControl {
    /// Eq. 5.5 with d measured online (open loop in everything but d): the thesis's.
    Formula,
    /// Closed loop: s follows the measured backlog of what neighbours lack (the default).
    Adaptive,
    /// s = `splits_per_step` throughout.
    Fixed,
}

impl Default for Bandwidth {
    fn default() -> Self {
        Bandwidth {
            control: SplitControl::Adaptive,
            usage: 0.5,
            splits_per_step: 2.0,
            min_splits_per_step: 0.05,
            max_splits_per_step: 8.0,
            split_bytes_prior: 10.0,
            p_comm: None,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Coordination {
    pub strategy: Strategy,
    /// β of the utility/cost trade-off U − β·V (thesis eq. 4.6; V normalized to [0, 1]).
    pub beta: f64,
    /// `decentralized`: a heard target's discount halves every this many steps; 0 = never
    /// (the thesis).
    pub target_half_life_steps: f64,
    /// Path costs punish cells near obstacles: a step into a cell costs (1 + weight × the
    /// Gaussian-blurred (σ cells) occupancy there) times its length; 0 = off.
    pub obstacle_penalty: f64,
    pub obstacle_sigma_cells: f64,
    /// `burgard`: Algorithm 2's randomized permutation search instead of greedy Algorithm 1.
    pub burgard_search: bool,
    /// `burgard`: random changes tried by the permutation search.
    pub search_tries: u32,
    /// `burgard`: the sub-team reassigns at least this often (and whenever a member's target is
    /// reached or the sub-team changes).
    pub replan_every_steps: u32,
    /// `bids` (Simmons et al. 2000): bids, the central executive and the fallback.
    pub bids: Bids,
    /// `roles` (de Hoog et al. 2010): the team hierarchy, rendezvous and role swaps.
    pub roles: Roles,
    /// `pack` (Rooker & Birk 2005): random configuration changes scored by the utility.
    pub pack: Pack,
}

/// `coordination.pack`: Rooker and Birk's communicative exploration (robot-agent's
/// `coord::pack`): the leader of each connected group scores `configurations` random
/// configuration changes per step and sends the best as moves.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Pack {
    /// k, the random configuration changes scored per step (the paper: 50).
    pub configurations: u32,
    /// The utility of a robot's new position on (or a step nearer to) a frontier (the paper: 1).
    pub frontier_utility: f64,
    /// The utility of any other possible position (the paper: 0).
    pub other_utility: f64,
    /// The utility of an impossible position: an obstacle, unknown space, a teammate's new
    /// position (the paper: −100).
    pub impossible_utility: f64,
    /// δ, added to a configuration whose communication graph is not connected (the paper: −10).
    pub disconnect_penalty: f64,
}

impl Default for Pack {
    fn default() -> Self {
        Pack {
            configurations: 50,
            frontier_utility: 1.0,
            other_utility: 0.0,
            impossible_utility: -100.0,
            disconnect_penalty: -10.0,
        }
    }
}

/// `coordination.roles`: de Hoog, Cameron and Visser's role-based exploration (robot-agent's
/// `coord::roles`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Roles {
    /// Branches below the base station; 0: as many as it takes to give every branch
    /// `relays_per_branch` relays and an explorer (the last branch may be shorter).
    pub branches: u32,
    /// Relays between the base station and the explorer of a branch.
    pub relays_per_branch: u32,
    /// The role swap rule (§V): the dynamic hierarchy; off, the roles stay as dealt.
    pub swap: bool,
    /// Rendezvous points nearest the explorer's next frontier that it chooses among.
    pub candidates: u32,
    /// Algorithm 1's filling distance T₁ (m): skeleton points this far from every rendezvous
    /// point so far become one.
    pub fill_m: f64,
    /// Algorithm 1's pruning distance T₂ (m): of two rendezvous points closer than this, one goes.
    pub prune_m: f64,
    /// Steps a robot waits at a rendezvous past the agreed step before it tries the fallback.
    pub patience_steps: u32,
    /// While in range of its parent, an explorer agrees a new rendezvous at least this often.
    pub refresh_steps: u32,
    /// At a meeting, the most steps a robot stays for what it carries to cross the radio.
    pub linger_steps: u32,
    /// A robot sends its role state to each robot in range when it changes and at least this often.
    pub status_every_steps: u32,
}

impl Default for Roles {
    fn default() -> Self {
        Roles {
            branches: 0,
            relays_per_branch: 1,
            swap: true,
            candidates: 5,
            fill_m: 4.0,
            prune_m: 2.0,
            patience_steps: 10,
            refresh_steps: 5,
            linger_steps: 10,
            status_every_steps: 10,
        }
    }
}

/// `coordination.bids`: Simmons et al.'s bids and central executive (robot-agent's `coord::bids`
/// and `coord::executive`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Bids {
    /// The most frontier cells one bid offers.
    pub offers: u32,
    /// The most bytes one bid may take on the radio (offers beyond it are left out).
    pub max_bid_bytes: u32,
    /// Frontier cells of a bid are at least this far apart (the paper: about a robot radius).
    pub frontier_spacing_m: f64,
    /// The nominal sensor range of the information gain (m).
    pub gain_range_m: f64,
    /// Net utility = gain (m² of unknown area) − `cost_weight` × path cost (m).
    pub cost_weight: f64,
    /// The executive assigns nothing whose discounted gain is at most this (m²).
    pub min_gain_m2: f64,
    /// Gains of frontier cells inside the IGR of a robot's current task are divided by this.
    pub hysteresis: f64,
    /// Steps the executive waits after a new bid for others before it assigns.
    pub wait_steps: u32,
    /// A robot with no assignment younger than this decides alone on its own bid.
    pub assignment_timeout_steps: u32,
    /// A robot bids again once this much of its planning grid (m²) changed since its last bid,
    /// or when its task is reached or no longer a frontier.
    pub rebid_changed_m2: f64,
}

impl Default for Bids {
    fn default() -> Self {
        Bids {
            offers: 8,
            max_bid_bytes: 256,
            frontier_spacing_m: 0.3,
            gain_range_m: 2.0,
            cost_weight: 1.0,
            min_gain_m2: 0.0,
            hysteresis: 0.85,
            wait_steps: 1,
            assignment_timeout_steps: 10,
            rebid_changed_m2: 2.0,
        }
    }
}

/// `[base_station]`: a radio node that does not move or sense (robot-agent's `base`), node id
/// `robots.count`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BaseStation {
    pub enabled: bool,
    /// Where it stands, `[x, y]` in metres; `None`: in the robots' spawn area.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pose: Option<[f64; 2]>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Strategy {
    Decentralized,
    Burgard,
    Uncoordinated,
    Bids,
    Roles,
    Pack,
}

impl Default for Scenario {
    fn default() -> Self {
        Scenario {
            seed: 1,
            max_steps: None,
            done_pct: 99.0,
            clock: Clock::default(),
            world: World::default(),
            robots: Robots::default(),
            sensor: Sensor::default(),
            radio: Radio::default(),
            exchange: Exchange::default(),
            bandwidth: Bandwidth::default(),
            coordination: Coordination::default(),
            base_station: BaseStation::default(),
            netem: Netem::default(),
            supervise: Supervise::default(),
            faults: Vec::new(),
        }
    }
}

impl Default for Clock {
    fn default() -> Self {
        Clock {
            mode: ClockMode::Lockstep,
            markers: true,
            step_seconds: 1.0,
            step_timeout_ms: 2000,
            dead_after: 5,
            speedup: 1.0,
        }
    }
}

impl Default for World {
    fn default() -> Self {
        World {
            map: "intel_lab".into(),
            resolution_m: 0.2,
            width_m: 40.0,
            height_m: 30.0,
        }
    }
}

impl Default for Robots {
    fn default() -> Self {
        Robots {
            count: 4,
            speed_m_per_s: 0.5,
            radius_m: 0.15,
            spawn_spacing_m: 0.6,
            spawn_clearance_m: 0.8,
        }
    }
}

impl Default for Sensor {
    fn default() -> Self {
        Sensor {
            beams: 360,
            fov_deg: 360.0,
            max_range_m: 8.0,
            noise_std_m: 0.0,
        }
    }
}

impl Default for Radio {
    fn default() -> Self {
        Radio {
            model: RadioModel::Disk,
            range_m: 10.0,
            range_pct_of_diagonal: None,
            bandwidth_bytes_per_s: 1000,
            medium: Medium::PerLink,
            latency_ms: 0.0,
            jitter_ms: 0.0,
            pathloss_ref_dbm: -40.0,
            pathloss_ref_distance_m: 1.0,
            pathloss_exponent: 2.0,
            pathloss_wall_attenuation_db: 3.1,
            pathloss_max_walls: 4,
            pathloss_threshold_dbm: None,
            interference_range_m: None,
            frame_loss: 0.0,
            shadowing_db: 0.0,
            fading_db: 0.0,
        }
    }
}

impl Default for Exchange {
    fn default() -> Self {
        Exchange {
            mode: ExchangeMode::Polygon,
            hello_every_steps: 10,
            edge_bounds: true,
            snapshots: true,
            relay: Relay::Tree,
        }
    }
}

impl Default for Coordination {
    fn default() -> Self {
        Coordination {
            strategy: Strategy::Decentralized,
            beta: 1.0,
            target_half_life_steps: 0.0,
            obstacle_penalty: 0.0,
            obstacle_sigma_cells: 2.0,
            burgard_search: false,
            search_tries: 200,
            replan_every_steps: 10,
            bids: Bids::default(),
            roles: Roles::default(),
            pack: Pack::default(),
        }
    }
}

/// A scenario that could not be read; every variant renders as one line naming the key.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ScenarioError {
    #[error("cannot read scenario {path}: {reason}")]
    Read { path: PathBuf, reason: String },
    #[error("scenario is not valid TOML: {0}")]
    Syntax(String),
    #[error("unknown key `{key}` (allowed here: {allowed})")]
    UnknownKey { key: String, allowed: String },
    #[error("key `{key}` has a {got} value, expected {want}")]
    WrongType {
        key: String,
        got: &'static str,
        want: &'static str,
    },
    #[error("key `{key}` = {value}: {allowed}")]
    Invalid {
        key: String,
        value: String,
        allowed: String,
    },
    #[error("override `{0}` is not of the form KEY=VALUE")]
    BadOverride(String),
}

/// The worlds generated from the seed rather than loaded from a file (`world.map`): the one list
/// that validation, the world-server's generator, error messages and the docs use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
/// What each one is: [`GeneratedWorld::about`].
pub enum GeneratedWorld {
    Unstructured,
    Mixed,
    Office,
    Corridor,
    TwoCorridors,
    Empty,
    Random,
    Library,
}

impl GeneratedWorld {
    /// Every generated world, in the order the docs list them.
    pub const ALL: [GeneratedWorld; 8] = [
        GeneratedWorld::Unstructured,
        GeneratedWorld::Mixed,
        GeneratedWorld::Office,
        GeneratedWorld::Corridor,
        GeneratedWorld::TwoCorridors,
        GeneratedWorld::Empty,
        GeneratedWorld::Random,
        GeneratedWorld::Library,
    ];

    /// The name `world.map` takes.
    pub const fn name(self) -> &'static str {
        match self {
            GeneratedWorld::Unstructured => "unstructured",
            GeneratedWorld::Mixed => "mixed",
            GeneratedWorld::Office => "office",
            GeneratedWorld::Corridor => "corridor",
            GeneratedWorld::TwoCorridors => "two-corridors",
            GeneratedWorld::Empty => "empty",
            GeneratedWorld::Random => "random",
            GeneratedWorld::Library => "library",
        }
    }

    /// What the world is, in a line (`swarm maps`).
    pub const fn about(self) -> &'static str {
        match self {
            GeneratedWorld::Unstructured => "rooms and clutter without a plan (the thesis's unstructured environment)",
            GeneratedWorld::Mixed => "offices and unstructured parts side by side (the thesis's mixed environment)",
            GeneratedWorld::Office => "rooms along corridors (the thesis's office environment)",
            GeneratedWorld::Corridor => "Simmons et al. (2000), environment A: an office along one corridor",
            GeneratedWorld::TwoCorridors => "Simmons et al. (2000), environment B: an office along two parallel corridors",
            GeneratedWorld::Empty => "Simmons et al. (2000), environment C: one obstacle-free room",
            GeneratedWorld::Random => "Simmons et al. (2000), environments D/E: 15 % of the floor covered by random obstacles",
            GeneratedWorld::Library => "de Hoog et al. (2010)'s library floor: a hall of shelf rows ringed by rooms",
        }
    }

    /// Every name, `|`-separated (for error messages).
    pub fn names() -> String {
        GeneratedWorld::ALL.map(GeneratedWorld::name).join("|")
    }
}

impl std::str::FromStr for GeneratedWorld {
    type Err = String;

    /// A generated world by its name; the error names them all.
    fn from_str(s: &str) -> Result<GeneratedWorld, String> {
        GeneratedWorld::ALL
            .into_iter()
            .find(|w| w.name() == s)
            .ok_or_else(|| format!("{s:?} is no generated world ({})", GeneratedWorld::names()))
    }
}

/// The fewest steps of a derived step limit (the fixed default before limits were derived).
pub const DERIVED_MAX_STEPS_MIN: u32 = 3000;
/// The most steps of a derived step limit.
pub const DERIVED_MAX_STEPS_MAX: u32 = 1_000_000;
/// The width of the strip a robot is taken to clear of unknown cells per metre it drives, when
/// its sensor reaches at least half of it: indoors, walls hide most of what a longer range would
/// reach (one robot on intel_lab clears 369 m² in 1 100 steps of 0.5 m: 0.67 m per metre).
const CLEARED_STRIP_M: f64 = 1.0;

impl Scenario {
    /// The step limit of a scenario that leaves `max_steps` out, for a world of `reachable_cells`
    /// free cells reachable from the spawn area: twice the steps one robot needs to drive a
    /// lawn-mower path over that area with strips [`CLEARED_STRIP_M`] wide (narrower when the
    /// sensor's range is shorter than half of it) at `robots.speed_m_per_s`. The team's size does
    /// not enter: a team is never slower than its one robot, so the limit is generous for
    /// teams; it is only a limit — a run ends as soon as it is explored. Clamped to
    /// [[`DERIVED_MAX_STEPS_MIN`], [`DERIVED_MAX_STEPS_MAX`]].
    pub fn derived_max_steps(&self, reachable_cells: usize) -> u32 {
        let area_m2 = reachable_cells as f64 * self.world.resolution_m.powi(2);
        let strip_m = CLEARED_STRIP_M.min(2.0 * self.sensor.max_range_m);
        let metres_per_step = self.robots.speed_m_per_s * self.clock.step_seconds;
        let steps = (2.0 * area_m2 / (strip_m * metres_per_step)).round();
        if steps.is_nan() {
            return DERIVED_MAX_STEPS_MAX;
        }
        steps.clamp(
            f64::from(DERIVED_MAX_STEPS_MIN),
            f64::from(DERIVED_MAX_STEPS_MAX),
        ) as u32
    }

    /// The lease of every sim-plane session (wall milliseconds): zenoh's own, 10 s
    /// ([`SIM_LEASE_MS`]); in lockstep at least as long as the world takes to declare a silent
    /// robot dead at the start (`dead_after` start allowances of
    /// [`crate::step_wait`]), at most an hour. A process starved of CPU on a loaded machine
    /// (128 robots on two cores: for more than 10 s) is then judged by the world's step clock
    /// rather than dropped by zenoh first; one that exits or is killed closes its connection
    /// and is noticed at once whatever the lease.
    pub fn sim_lease_ms(&self) -> u64 {
        match self.clock.mode {
            ClockMode::Lockstep => self
                .start_step_wait_ms()
                .saturating_mul(u64::from(self.clock.dead_after))
                .clamp(SIM_LEASE_MS, LOCKSTEP_RADIO_LEASE_MS),
            ClockMode::Realtime => SIM_LEASE_MS,
        }
    }

    /// The lockstep wait for a step before one has come in whole: `clock.step_timeout_ms` for
    /// every 8 nodes ([`crate::step_wait::start_ms`]).
    pub fn start_step_wait_ms(&self) -> u64 {
        crate::step_wait::start_ms(self.clock.step_timeout_ms, usize::from(self.nodes()))
    }

    /// The wall-clock wait for lockstep steps ([`crate::step_wait`]): at least
    /// `clock.step_timeout_ms`, the start allowance until a step is whole, then ten times the
    /// longest recent whole step.
    pub fn step_wait(&self) -> crate::step_wait::StepWait {
        crate::step_wait::StepWait::new(
            Duration::from_millis(self.clock.step_timeout_ms),
            Duration::from_millis(self.start_step_wait_ms()),
        )
    }

    /// The run's step limit: `max_steps`, which resolving a scenario always sets (see
    /// [`Scenario::derived_max_steps`]); an unresolved scenario without one has no limit.
    pub fn step_limit(&self) -> u32 {
        self.max_steps.unwrap_or(u32::MAX)
    }

    /// Reads a scenario file and applies `KEY=VALUE` overrides.
    pub fn load(path: &Path, overrides: &[String]) -> Result<Scenario, ScenarioError> {
        let text = std::fs::read_to_string(path).map_err(|e| ScenarioError::Read {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
        Scenario::from_toml(&text, overrides)
    }

    /// Parses scenario text and applies `KEY=VALUE` overrides.
    pub fn from_toml(text: &str, overrides: &[String]) -> Result<Scenario, ScenarioError> {
        let mut table: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| ScenarioError::Syntax(one_line(&e)))?;
        for o in overrides {
            apply_override(&mut table, o)?;
        }
        let schema = toml::Table::try_from(Scenario::default())
            .map_err(|e| ScenarioError::Syntax(e.to_string()))?;
        check_keys(&table, &schema, "")?;
        let scenario: Scenario = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| ScenarioError::Syntax(one_line(&e)))?;
        scenario.validate()?;
        Ok(scenario)
    }

    /// The resolved scenario as TOML (written into every run directory).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }

    /// Range checks that the types alone cannot express.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        let s = self;
        s.clock.validate()?;
        if let Some(m) = s.max_steps {
            at_least("max_steps", f64::from(m), 1.0)?;
        }
        if !(s.done_pct > 0.0 && s.done_pct <= 100.0) {
            return Err(invalid("done_pct", s.done_pct, "must be in (0, 100]"));
        }
        s.validate_world()?;
        s.validate_robots()?;
        s.validate_sensor()?;
        s.radio.validate()?;
        s.validate_channel()?;
        s.netem.validate()?;
        s.validate_supervise()?;
        s.process_faults()?;
        at_least(
            "exchange.hello_every_steps",
            f64::from(s.exchange.hello_every_steps),
            1.0,
        )?;
        s.validate_bandwidth()?;
        s.validate_coordination()?;
        s.validate_bids()?;
        s.validate_roles()?;
        s.validate_pack()?;
        s.validate_base_station()
    }

    /// `radio.medium = "airtime"` and lossy links act through the step plan: lockstep with
    /// markers only.
    fn validate_channel(&self) -> Result<(), ScenarioError> {
        if self.clock.marked() {
            return Ok(());
        }
        if self.radio.medium == Medium::Airtime {
            return Err(invalid(
                "radio.medium",
                "\"airtime\"",
                "needs clock.mode = \"lockstep\" with clock.markers = true (use \"shared\" or \"per-link\")",
            ));
        }
        if self.radio.lossy() {
            let (key, v) = if self.radio.frame_loss > 0.0 {
                ("radio.frame_loss", self.radio.frame_loss)
            } else {
                ("radio.fading_db", self.radio.fading_db)
            };
            return Err(invalid(
                key,
                v,
                "frames are lost through the step plan: needs clock.mode = \"lockstep\" with clock.markers = true (or 0)",
            ));
        }
        Ok(())
    }

    /// `[world]`: a map named, a resolution and an extent in range.
    fn validate_world(&self) -> Result<(), ScenarioError> {
        if self.world.map.trim().is_empty() {
            return Err(invalid(
                "world.map",
                "\"\"",
                &format!(
                    "a map YAML path, a shipped map's name (`swarm maps`), or a generated world: {}",
                    GeneratedWorld::names()
                ),
            ));
        }
        if !(0.01..=2.0).contains(&self.world.resolution_m) {
            return Err(invalid(
                "world.resolution_m",
                self.world.resolution_m,
                "must be in [0.01, 2]",
            ));
        }
        for (key, v) in [
            ("world.width_m", self.world.width_m),
            ("world.height_m", self.world.height_m),
        ] {
            if !(5.0..=500.0).contains(&v) {
                return Err(invalid(key, v, "must be in [5, 500] metres"));
            }
        }
        Ok(())
    }

    /// `[robots]`: a team size in range, robots that fit and start apart.
    fn validate_robots(&self) -> Result<(), ScenarioError> {
        if !(1..=MAX_ROBOTS).contains(&self.robots.count) {
            return Err(invalid(
                "robots.count",
                self.robots.count,
                &format!("must be in 1..={MAX_ROBOTS}"),
            ));
        }
        positive("robots.speed_m_per_s", self.robots.speed_m_per_s)?;
        positive("robots.radius_m", self.robots.radius_m)?;
        positive("robots.spawn_spacing_m", self.robots.spawn_spacing_m)?;
        at_least(
            "robots.spawn_clearance_m",
            self.robots.spawn_clearance_m,
            0.0,
        )?;
        if self.robots.spawn_spacing_m < 2.0 * self.robots.radius_m {
            return Err(invalid(
                "robots.spawn_spacing_m",
                self.robots.spawn_spacing_m,
                "must be at least 2 × robots.radius_m, or robots would start in collision",
            ));
        }
        Ok(())
    }

    /// `[sensor]`: beams, field of view, range and noise in range.
    fn validate_sensor(&self) -> Result<(), ScenarioError> {
        if !(1..=4096).contains(&self.sensor.beams) {
            return Err(invalid(
                "sensor.beams",
                self.sensor.beams,
                "must be in 1..=4096",
            ));
        }
        if !(self.sensor.fov_deg > 0.0 && self.sensor.fov_deg <= 360.0) {
            return Err(invalid(
                "sensor.fov_deg",
                self.sensor.fov_deg,
                "must be in (0, 360]",
            ));
        }
        positive("sensor.max_range_m", self.sensor.max_range_m)?;
        at_least("sensor.noise_std_m", self.sensor.noise_std_m, 0.0)?;
        Ok(())
    }

    /// `[supervise]`: the world-server is never restarted, and restarts fit the log owners.
    fn validate_supervise(&self) -> Result<(), ScenarioError> {
        if self.supervise.restart.contains(&ProcessKind::WorldServer) {
            return Err(invalid(
                "supervise.restart",
                "world-server",
                "robot, netem or base-station: the world-server is the simulation, its loss ends the run",
            ));
        }
        let most = crate::msg::MAX_LIVES - 1;
        if self.supervise.max_restarts > most {
            return Err(invalid(
                "supervise.max_restarts",
                self.supervise.max_restarts,
                &format!(
                    "must be at most {most} (a restarted robot's log is owned by its next life)"
                ),
            ));
        }
        Ok(())
    }

    /// `[bandwidth]`: the splitting frequency's bounds (thesis eq. 5.5) in order.
    fn validate_bandwidth(&self) -> Result<(), ScenarioError> {
        let b = &self.bandwidth;
        if !(b.usage > 0.0 && b.usage <= 1.0) {
            return Err(invalid("bandwidth.usage", b.usage, "must be in (0, 1]"));
        }
        positive("bandwidth.min_splits_per_step", b.min_splits_per_step)?;
        at_least(
            "bandwidth.max_splits_per_step",
            b.max_splits_per_step,
            b.min_splits_per_step,
        )?;
        if !(b.splits_per_step >= b.min_splits_per_step
            && b.splits_per_step <= b.max_splits_per_step)
        {
            return Err(invalid(
                "bandwidth.splits_per_step",
                b.splits_per_step,
                &format!(
                    "must be within [min_splits_per_step, max_splits_per_step] = [{}, {}]",
                    b.min_splits_per_step, b.max_splits_per_step
                ),
            ));
        }
        positive("bandwidth.split_bytes_prior", b.split_bytes_prior)?;
        Ok(())
    }

    /// `[coordination]`: the utility's weights, and `bandwidth.p_comm` in (0, 1].
    fn validate_coordination(&self) -> Result<(), ScenarioError> {
        let c = &self.coordination;
        at_least("coordination.beta", c.beta, 0.0)?;
        at_least(
            "coordination.target_half_life_steps",
            c.target_half_life_steps,
            0.0,
        )?;
        at_least("coordination.obstacle_penalty", c.obstacle_penalty, 0.0)?;
        positive("coordination.obstacle_sigma_cells", c.obstacle_sigma_cells)?;
        at_least(
            "coordination.replan_every_steps",
            f64::from(c.replan_every_steps),
            1.0,
        )?;
        if let Some(p) = self.bandwidth.p_comm.filter(|p| !(*p > 0.0 && *p <= 1.0)) {
            return Err(invalid("bandwidth.p_comm", p, "must be in (0, 1]"));
        }
        Ok(())
    }

    /// `[base_station]`: a finite pose, and a base station where a strategy needs one.
    fn validate_base_station(&self) -> Result<(), ScenarioError> {
        if let Some([x, y]) = self.base_station.pose {
            if !(x.is_finite() && y.is_finite()) {
                return Err(invalid(
                    "base_station.pose",
                    format!("[{x}, {y}]"),
                    "must be two finite numbers [x, y] in metres",
                ));
            }
        }
        if self.coordination.strategy == Strategy::Bids && !self.base_station.enabled {
            return Err(invalid(
                "coordination.strategy",
                "\"bids\"",
                "needs the central executive's node: set base_station.enabled = true",
            ));
        }
        if self.coordination.strategy == Strategy::Roles && !self.base_station.enabled {
            return Err(invalid(
                "coordination.strategy",
                "\"roles\"",
                "needs the hierarchy's root: set base_station.enabled = true",
            ));
        }
        Ok(())
    }

    fn validate_bids(&self) -> Result<(), ScenarioError> {
        let b = &self.coordination.bids;
        at_least("coordination.bids.offers", f64::from(b.offers), 1.0)?;
        at_least(
            "coordination.bids.max_bid_bytes",
            f64::from(b.max_bid_bytes),
            64.0,
        )?;
        at_least(
            "coordination.bids.frontier_spacing_m",
            b.frontier_spacing_m,
            0.0,
        )?;
        positive("coordination.bids.gain_range_m", b.gain_range_m)?;
        at_least("coordination.bids.cost_weight", b.cost_weight, 0.0)?;
        at_least("coordination.bids.min_gain_m2", b.min_gain_m2, 0.0)?;
        if !(b.hysteresis > 0.0 && b.hysteresis <= 1.0) {
            return Err(invalid(
                "coordination.bids.hysteresis",
                b.hysteresis,
                "must be in (0, 1]",
            ));
        }
        at_least(
            "coordination.bids.assignment_timeout_steps",
            f64::from(b.assignment_timeout_steps),
            1.0,
        )?;
        at_least(
            "coordination.bids.rebid_changed_m2",
            b.rebid_changed_m2,
            0.0,
        )
    }

    fn validate_roles(&self) -> Result<(), ScenarioError> {
        let r = &self.coordination.roles;
        let n = u64::from(self.robots.count);
        let per = u64::from(r.relays_per_branch) + 1;
        if r.branches > 0 {
            let b = u64::from(r.branches);
            if b * per < n || (b - 1) * per >= n {
                return Err(invalid(
                    "coordination.roles.branches",
                    r.branches,
                    &format!(
                        "{} robots with {} relays per branch make {} branches (the last may be shorter); 0 derives it",
                        n,
                        r.relays_per_branch,
                        n.div_ceil(per)
                    ),
                ));
            }
        }
        at_least(
            "coordination.roles.candidates",
            f64::from(r.candidates),
            1.0,
        )?;
        at_least("coordination.roles.prune_m", r.prune_m, 0.0)?;
        at_least("coordination.roles.fill_m", r.fill_m, r.prune_m.max(0.1))?;
        at_least(
            "coordination.roles.refresh_steps",
            f64::from(r.refresh_steps),
            1.0,
        )?;
        at_least(
            "coordination.roles.status_every_steps",
            f64::from(r.status_every_steps),
            1.0,
        )
    }

    fn validate_pack(&self) -> Result<(), ScenarioError> {
        let p = &self.coordination.pack;
        if !(1..=100_000).contains(&p.configurations) {
            return Err(invalid(
                "coordination.pack.configurations",
                p.configurations,
                "must be in 1..=100000",
            ));
        }
        let utilities = [
            ("coordination.pack.frontier_utility", p.frontier_utility),
            ("coordination.pack.other_utility", p.other_utility),
            ("coordination.pack.impossible_utility", p.impossible_utility),
            ("coordination.pack.disconnect_penalty", p.disconnect_penalty),
        ];
        for (key, v) in utilities {
            if !v.is_finite() {
                return Err(invalid(key, v, "must be a finite number"));
            }
        }
        if p.frontier_utility <= p.other_utility {
            return Err(invalid(
                "coordination.pack.frontier_utility",
                p.frontier_utility,
                "must be above other_utility, or nothing draws the pack to frontiers",
            ));
        }
        if p.impossible_utility >= p.other_utility {
            return Err(invalid(
                "coordination.pack.impossible_utility",
                p.impossible_utility,
                "must be below other_utility",
            ));
        }
        if p.disconnect_penalty > 0.0 {
            return Err(invalid(
                "coordination.pack.disconnect_penalty",
                p.disconnect_penalty,
                "must be at most 0 (a penalty)",
            ));
        }
        Ok(())
    }

    /// Radio nodes: the robots, then the base station if there is one.
    pub fn nodes(&self) -> u16 {
        self.robots.count + u16::from(self.base_station.enabled)
    }

    /// The scenario's process faults (`[[faults]]` of the kinds in [`PROCESS_FAULT_KINDS`]) in
    /// step order, checked against the run's processes; the error names the table.
    pub fn process_faults(&self) -> Result<Vec<ProcessFault>, ScenarioError> {
        let mut out = Vec::new();
        for (i, t) in self.faults.iter().enumerate() {
            if !is_process_fault(t) {
                continue;
            }
            let key = format!("faults[{i}]");
            let kind = t.get("kind").map_or_else(String::new, ToString::to_string);
            let f: ProcessFault = toml::Value::Table(t.clone())
                .try_into()
                .map_err(|e: toml::de::Error| invalid(&key, &kind, &one_line(&e)))?;
            if let Err((value, why)) = self.check_process_action(&f.action) {
                return Err(invalid(&key, value, &why));
            }
            out.push(f);
        }
        out.sort_by_key(|f| f.step);
        Ok(out)
    }

    /// Whether `p` is one of the run's processes.
    pub fn has_process(&self, p: Process) -> bool {
        match p {
            Process::Robot(i) => i < self.robots.count,
            Process::BaseStation => self.base_station.enabled,
            Process::Netem | Process::WorldServer => true,
        }
    }

    /// Whether `action` can be done in this run: its process is one of the run's, and the
    /// action suits it (the world-server can be killed, not restarted; only a robot or the base
    /// station can be frozen). The error is (the value at fault, why).
    pub fn check_process_action(&self, action: &ProcessAction) -> Result<(), (String, String)> {
        let p = action.process();
        if !self.has_process(p) {
            return Err((
                p.to_string(),
                format!(
                    "no such process in this run: robot-0..robot-{}, netem, world-server{}",
                    self.robots.count.saturating_sub(1),
                    if self.base_station.enabled {
                        ", base-station"
                    } else {
                        ""
                    }
                ),
            ));
        }
        let refused = match (action, p) {
            (
                ProcessAction::Kill {
                    restart_after: Some(_),
                    ..
                }
                | ProcessAction::Restart { .. },
                Process::WorldServer,
            ) => Some(
                "the world-server is the simulation: it can be killed (ending the run), not restarted",
            ),
            (
                ProcessAction::Freeze { .. } | ProcessAction::Thaw { .. },
                Process::Netem | Process::WorldServer,
            ) => Some("only a robot or the base station can be frozen and thawed"),
            _ => None,
        };
        match refused {
            Some(why) => Err((action.name().to_string(), why.to_string())),
            None => Ok(()),
        }
    }

    /// The base station's node id (`robots.count`), if there is one.
    pub fn base_id(&self) -> Option<u16> {
        self.base_station.enabled.then_some(self.robots.count)
    }

    /// The world is generated from the seed (not loaded from a file).
    pub fn world_is_generated(&self) -> bool {
        self.world.map.parse::<GeneratedWorld>().is_ok()
    }

    pub fn laser(&self) -> crate::geom::LaserSpec {
        crate::geom::LaserSpec {
            beams: self.sensor.beams,
            fov_rad: self.sensor.fov_deg.to_radians(),
            max_range_m: self.sensor.max_range_m,
            noise_std_m: self.sensor.noise_std_m,
        }
    }
}

fn one_line(e: &toml::de::Error) -> String {
    let msg = e.message().trim().replace('\n', " ");
    match e.span() {
        Some(span) => format!("{msg} (at byte {})", span.start),
        None => msg,
    }
}

fn invalid(key: &str, value: impl std::fmt::Display, allowed: &str) -> ScenarioError {
    ScenarioError::Invalid {
        key: key.into(),
        value: value.to_string(),
        allowed: allowed.into(),
    }
}

fn positive(key: &str, v: f64) -> Result<(), ScenarioError> {
    if v > 0.0 && v.is_finite() {
        Ok(())
    } else {
        Err(invalid(key, v, "must be a positive number"))
    }
}

fn at_least(key: &str, v: f64, min: f64) -> Result<(), ScenarioError> {
    if v >= min && v.is_finite() {
        Ok(())
    } else {
        Err(invalid(key, v, &format!("must be at least {min}")))
    }
}

/// Applies `a.b.c=VALUE`: VALUE is read as a TOML value, or as a bare string if it is not one
/// (so `--set world.map=office` needs no quotes).
fn apply_override(table: &mut toml::Table, o: &str) -> Result<(), ScenarioError> {
    let (key, raw) = o
        .split_once('=')
        .ok_or_else(|| ScenarioError::BadOverride(o.into()))?;
    let key = key.trim();
    if key.is_empty() || key.split('.').any(str::is_empty) {
        return Err(ScenarioError::BadOverride(o.into()));
    }
    let value = format!("v = {}", raw.trim())
        .parse::<toml::Table>()
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.trim().to_string()));
    let mut parts: Vec<&str> = key.split('.').collect();
    let last = parts.pop().unwrap_or(key);
    let mut t = table;
    let mut path = String::new();
    for p in parts {
        path = if path.is_empty() {
            p.to_string()
        } else {
            format!("{path}.{p}")
        };
        let entry = t
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        t = entry
            .as_table_mut()
            .ok_or_else(|| ScenarioError::WrongType {
                key: path.clone(),
                got: type_name(&toml::Value::Boolean(false)),
                want: "table",
            })?;
    }
    t.insert(last.to_string(), value);
    Ok(())
}

fn type_name(v: &toml::Value) -> &'static str {
    match v {
        toml::Value::String(_) => "string",
        toml::Value::Integer(_) => "integer",
        toml::Value::Float(_) => "float",
        toml::Value::Boolean(_) => "boolean",
        toml::Value::Datetime(_) => "datetime",
        toml::Value::Array(_) => "array",
        toml::Value::Table(_) => "table",
    }
}

/// Keys without a default value (absent from the serialized default), accepted as numbers.
const OPTIONAL_FLOAT_KEYS: [&str; 2] = [
    "radio.pathloss_threshold_dbm",
    "radio.range_pct_of_diagonal",
];

/// Keys without a default value, accepted as whole numbers.
const OPTIONAL_INT_KEYS: [&str; 1] = ["max_steps"];

/// Keys without a default value, accepted as arrays of two numbers.
const OPTIONAL_PAIR_KEYS: [&str; 1] = ["base_station.pose"];

/// Checks every key of `user` against `schema` (the serialized default scenario), naming the
/// full dotted key of the first unknown key or wrong type. Integers are accepted where floats are
/// expected (and converted in place).
fn check_keys(user: &toml::Table, schema: &toml::Table, prefix: &str) -> Result<(), ScenarioError> {
    for (k, v) in user {
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        let optional = OPTIONAL_FLOAT_KEYS.contains(&key.as_str());
        if optional && matches!(v, toml::Value::Float(_) | toml::Value::Integer(_)) {
            continue;
        }
        if OPTIONAL_INT_KEYS.contains(&key.as_str()) {
            match v {
                toml::Value::Integer(i) if *i < 0 => {
                    return Err(invalid(&key, i, "must not be negative"));
                }
                toml::Value::Integer(_) => continue,
                other => {
                    return Err(ScenarioError::WrongType {
                        key,
                        got: type_name(other),
                        want: "integer",
                    })
                }
            }
        }
        if OPTIONAL_PAIR_KEYS.contains(&key.as_str()) {
            let pair = v.as_array().filter(|a| {
                a.len() == 2
                    && a.iter()
                        .all(|x| matches!(x, toml::Value::Float(_) | toml::Value::Integer(_)))
            });
            if pair.is_none() {
                return Err(invalid(&key, v, "must be [x, y] in metres"));
            }
            continue;
        }
        let Some(want) = schema.get(k) else {
            let allowed: Vec<&str> = schema.keys().map(String::as_str).collect();
            return Err(ScenarioError::UnknownKey {
                key,
                allowed: allowed.join(", "),
            });
        };
        match (v, want) {
            (toml::Value::Table(u), toml::Value::Table(s)) => check_keys(u, s, &key)?,
            (toml::Value::Integer(_), toml::Value::Float(_)) => {}
            (toml::Value::Integer(i), toml::Value::Integer(_)) if *i < 0 => {
                return Err(invalid(&key, i, "must not be negative"));
            }
            (u, s) if std::mem::discriminant(u) == std::mem::discriminant(s) => {}
            (u, s) => {
                return Err(ScenarioError::WrongType {
                    key,
                    got: type_name(u),
                    want: type_name(s),
                })
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_generated_world_parses_back_from_its_name() {
        for w in GeneratedWorld::ALL {
            assert_eq!(w.name().parse::<GeneratedWorld>(), Ok(w));
        }
        let Err(e) = "maze".parse::<GeneratedWorld>() else {
            panic!("maze is no generated world");
        };
        assert!(e.contains("two-corridors") && e.contains("library"), "{e}");
    }

    fn err(text: &str, overrides: &[&str]) -> String {
        let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
        match Scenario::from_toml(text, &o) {
            Ok(_) => panic!("expected an error for {text:?} {overrides:?}"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn the_sim_lease_outlasts_the_worlds_verdict_in_lockstep_within_bounds() {
        let mut s = Scenario::default();
        // The default: 5 step timeouts of 2 s, zenoh's own 10 s.
        assert_eq!(s.sim_lease_ms(), SIM_LEASE_MS);
        s.clock.step_timeout_ms = 600_000;
        assert_eq!(s.sim_lease_ms(), 3_000_000);
        s.clock.step_timeout_ms = u64::MAX;
        assert_eq!(s.sim_lease_ms(), LOCKSTEP_RADIO_LEASE_MS);
        s.clock.step_timeout_ms = 1;
        assert_eq!(s.sim_lease_ms(), SIM_LEASE_MS);
        s.clock.step_timeout_ms = 600_000;
        s.clock.mode = ClockMode::Realtime;
        assert_eq!(s.sim_lease_ms(), SIM_LEASE_MS);
    }

    #[test]
    fn max_steps_may_be_left_out_and_is_a_whole_number_when_given() {
        let s = Scenario::from_toml("", &[]).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(s.max_steps, None);
        assert!(!s.to_toml().contains("max_steps"));
        let s = Scenario::from_toml("max_steps = 40", &[]).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(s.max_steps, Some(40));
        assert!(s.to_toml().contains("max_steps = 40"));
        assert!(err("", &["max_steps=-3"]).contains("must not be negative"));
        assert!(err("", &["max_steps=0"]).contains("max_steps"));
        assert!(err("max_steps = 1.5", &[]).contains("integer"));
        assert!(err("max_steps = \"auto\"", &[]).contains("integer"));
    }

    #[test]
    fn a_derived_step_limit_grows_with_the_area_and_shrinks_with_speed_and_range() {
        let s = Scenario::default();
        // 0.2 m cells: 25 a square metre; 1 m strips at 0.5 m a step: 4 steps a square metre.
        assert_eq!(s.derived_max_steps(25 * 1000), 4000);
        assert_eq!(s.derived_max_steps(25 * 2000), 8000);
        assert_eq!(s.derived_max_steps(0), DERIVED_MAX_STEPS_MIN);
        assert_eq!(s.derived_max_steps(usize::MAX), DERIVED_MAX_STEPS_MAX);
        let mut fast = s.clone();
        fast.robots.speed_m_per_s = 1.0;
        assert_eq!(fast.derived_max_steps(25 * 2000), 4000);
        let mut short = s.clone();
        short.sensor.max_range_m = 0.25;
        assert_eq!(short.derived_max_steps(25 * 1000), 8000);
        let mut long = s;
        long.sensor.max_range_m = 30.0;
        assert_eq!(long.derived_max_steps(25 * 1000), 4000);
    }

    #[test]
    fn empty_file_is_the_default() {
        assert_eq!(Scenario::from_toml("", &[]), Ok(Scenario::default()));
    }

    #[test]
    fn default_round_trips_through_toml() {
        let s = Scenario::default();
        assert_eq!(Scenario::from_toml(&s.to_toml(), &[]), Ok(s));
    }

    #[test]
    fn shipped_default_toml_is_the_built_in_default() {
        let text = include_str!("../../configs/default.toml");
        assert_eq!(Scenario::from_toml(text, &[]), Ok(Scenario::default()));
    }

    #[test]
    fn overrides_set_nested_keys_and_bare_strings() {
        let s = Scenario::from_toml(
            "",
            &[
                "robots.count=8".into(),
                "radio.range_m=10".into(),
                "world.map=office".into(),
            ],
        )
        .unwrap_or_default();
        assert_eq!(s.robots.count, 8);
        assert_eq!(s.radio.range_m, 10.0);
        assert_eq!(s.world.map, "office");
        assert!(s.world_is_generated());
    }

    #[test]
    fn errors_name_the_key_on_one_line() {
        let cases = [
            (err("[radio]\nrnage_m = 3\n", &[]), "radio.rnage_m"),
            (err("", &["robots.count=abc"]), "robots.count"),
            (err("", &["robots.count=0"]), "robots.count"),
            (err("", &["robots.count=-2"]), "robots.count"),
            (err("", &["robots.count=1001"]), "1..=1000"),
            (err("", &["done_pct=150"]), "done_pct"),
            (err("", &["nope.x=1"]), "nope"),
            (err("", &["clock.mode=\"sometimes\""]), "sometimes"),
            (err("[sensor]\nbeams = 1.5\n", &[]), "sensor.beams"),
            (err("", &["novalue"]), "novalue"),
            (err("seed = [", &[]), "TOML"),
            (
                err("", &["coordination.strategy=\"bids\""]),
                "base_station.enabled",
            ),
            (
                err("", &["coordination.strategy=\"roles\""]),
                "base_station.enabled",
            ),
            (
                err("", &["coordination.pack.configurations=0"]),
                "coordination.pack.configurations",
            ),
            (
                err("", &["coordination.pack.frontier_utility=0"]),
                "coordination.pack.frontier_utility",
            ),
            (
                err("", &["coordination.pack.disconnect_penalty=5"]),
                "coordination.pack.disconnect_penalty",
            ),
            (
                err("", &["robots.count=10", "coordination.roles.branches=3"]),
                "coordination.roles.branches",
            ),
            (
                err(
                    "",
                    &[
                        "coordination.roles.fill_m=1",
                        "coordination.roles.prune_m=2",
                    ],
                ),
                "coordination.roles.fill_m",
            ),
            (
                err("", &["coordination.bids.hysteresis=0"]),
                "coordination.bids.hysteresis",
            ),
            (err("", &["base_station.pose=[1]"]), "base_station.pose"),
            (
                err("", &["base_station.pose=\"here\""]),
                "base_station.pose",
            ),
            (err("", &["coordination.beta=-1"]), "coordination.beta"),
            (
                err("", &["coordination.replan_every_steps=0"]),
                "coordination.replan_every_steps",
            ),
            (err("", &["bandwidth.usage=0"]), "bandwidth.usage"),
            (err("", &["bandwidth.control=\"magic\""]), "magic"),
            (err("", &["bandwidth.p_comm=2"]), "bandwidth.p_comm"),
            (
                err("", &["bandwidth.splits_per_step=100"]),
                "bandwidth.splits_per_step",
            ),
        ];
        for (msg, needle) in cases {
            assert!(msg.contains(needle), "{msg:?} should name {needle:?}");
            assert!(!msg.contains('\n'), "{msg:?} must be one line");
        }
    }
}
