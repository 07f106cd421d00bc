//! What a robot shares over the radio and how its peers' shares become part of its planning
//! grid (DESIGN.md §4.8; `exchange.mode`):
//!
//! * `raw-scans` — the baseline: every robot's laser scans, relayed transitively; received
//!   scans are integrated into a grid of the peers' knowledge (never overriding G_s).
//! * `polygon` — the thesis: every robot's op log of its incremental approximation A_t
//!   (Algorithm 10 steps 2–6, [`crate::mapper`]), relayed transitively; the planning grid is
//!   merged from G_s and every peer's approximation at its last save point (Algorithm 9).
//!
//! * `grid-snapshots` — the second baseline: per step, the cells of G_s the scan changed,
//!   relayed transitively and written into a grid of the peers' knowledge (never overriding
//!   G_s).
//!
//! All speak the same handshake (`conn`) and budget rules; only the records differ.

use proto::geom::{LaserSpec, MapInfo};
use proto::grid::{Cell, Grid, Occ};
use proto::msg::{encode, Hello, OpChunk, PatchDelta, RobotId, Scan, ScanDelta, WorldInfo};
use proto::scenario::{ExchangeMode, RadioModel, Scenario};

use crate::approx_exchange::ApproxExchange;
use crate::exchange::DeltaOutcome;
use crate::grid::Evidence;
use crate::grid_snapshots::{apply_patch, patch_of, GridPatchExchange};
use crate::mapper::Mapper;
use crate::merge::merge;
use crate::raw_scans::{scan_ranges, scan_record, RawScanExchange};
use crate::splitting::{p_comm, SplittingFrequency};

/// One message to a neighbour.
#[derive(Clone, Debug, PartialEq)]
pub enum Share {
    Scans(ScanDelta),
    Ops(OpChunk),
    Patches(PatchDelta),
}

impl Share {
    /// The message as sent on the radio.
    pub fn encode(&self) -> Vec<u8> {
        match self {
            Share::Scans(d) => encode(d),
            Share::Ops(c) => encode(c),
            Share::Patches(d) => encode(d),
        }
    }

    /// The radio key it is sent on to robot `to`.
    pub fn key(&self, to: RobotId) -> String {
        match self {
            Share::Scans(_) => proto::keys::radio_delta(to),
            Share::Ops(_) => proto::keys::radio_ops(to),
            Share::Patches(_) => proto::keys::radio_patch(to),
        }
    }
}

/// A robot's side of the exchange, by mode.
#[derive(Clone, Debug)]
pub enum Sharing {
    RawScans {
        exchange: RawScanExchange,
        /// What peers' scans told this robot, and the beam counts behind it.
        others: Grid,
        evidence: Evidence,
    },
    Polygon {
        exchange: ApproxExchange,
        mapper: Box<Mapper>,
        splitting: SplittingFrequency,
    },
    GridSnapshots {
        exchange: GridPatchExchange,
        /// What peers' patches told this robot.
        others: Grid,
    },
}

impl Sharing {
    /// Robot `me`'s sharing in scenario `s`'s exchange mode, in `world`, with a link budget of
    /// `budget` bytes per step (`None`: unlimited).
    pub fn new(s: &Scenario, me: RobotId, world: &WorldInfo, budget: Option<f64>) -> Sharing {
        let empty = Grid::new(world.map.width, world.map.height, Occ::Unknown);
        match s.exchange.mode {
            ExchangeMode::Polygon => {
                let m = &world.map;
                let p = match s.radio.model {
                    RadioModel::Always => 1.0,
                    RadioModel::Disk | RadioModel::Pathloss => p_comm(
                        s.radio.range_m,
                        f64::from(m.width) * m.resolution_m,
                        f64::from(m.height) * m.resolution_m,
                        u32::from(world.robots),
                    ),
                };
                let splitting =
                    SplittingFrequency::new(&s.bandwidth, u32::from(world.robots), budget, p);
                Sharing::Polygon {
                    exchange: ApproxExchange::new(me),
                    mapper: Box::new(Mapper::new(splitting.current())),
                    splitting,
                }
            }
            ExchangeMode::GridSnapshots => Sharing::GridSnapshots {
                exchange: GridPatchExchange::new(me),
                others: empty,
            },
            ExchangeMode::RawScans => Sharing::RawScans {
                exchange: RawScanExchange::new(me),
                evidence: Evidence::new(&empty),
                others: empty,
            },
        }
    }

    /// Records this step's own contribution: the scan (raw-scans), or the mapping pipeline's
    /// ops for G_s after the scan (polygon; `changed` are the cells the scan changed).
    pub fn after_scan(&mut self, scan: &Scan, laser: &LaserSpec, own: &Grid, changed: &[Cell]) {
        match self {
            Sharing::RawScans { exchange, .. } => {
                match scan_record(scan.step, scan.pose, &scan.ranges, laser) {
                    Ok(rec) => exchange.record_own(rec),
                    Err(e) => tracing::warn!("scan of step {} not shared: {e}", scan.step),
                }
            }
            Sharing::Polygon {
                exchange,
                mapper,
                splitting,
            } => {
                let first = mapper.log().len();
                mapper.splits_per_step = splitting.current();
                let report = mapper.step(own, changed);
                splitting.record(report.splits, report.bytes);
                exchange.record_own(mapper.log().since(first));
            }
            Sharing::GridSnapshots { exchange, .. } => {
                if !changed.is_empty() {
                    exchange.record_own(patch_of(scan.step, own, changed));
                }
            }
        }
    }

    pub fn knowledge(&self) -> Hello {
        match self {
            Sharing::RawScans { exchange, .. } => exchange.knowledge(),
            Sharing::Polygon { exchange, .. } => exchange.knowledge(),
            Sharing::GridSnapshots { exchange, .. } => exchange.knowledge(),
        }
    }

    pub fn on_hello(&mut self, h: &Hello) {
        match self {
            Sharing::RawScans { exchange, .. } => exchange.on_hello(h),
            Sharing::Polygon { exchange, .. } => exchange.on_hello(h),
            Sharing::GridSnapshots { exchange, .. } => exchange.on_hello(h),
        }
    }

    pub fn link_up(&mut self, peer: RobotId) {
        match self {
            Sharing::RawScans { exchange, .. } => exchange.link_up(peer),
            Sharing::Polygon { exchange, .. } => exchange.link_up(peer),
            Sharing::GridSnapshots { exchange, .. } => exchange.link_up(peer),
        }
    }

    pub fn link_down(&mut self, peer: RobotId) {
        match self {
            Sharing::RawScans { exchange, .. } => exchange.link_down(peer),
            Sharing::Polygon { exchange, .. } => exchange.link_down(peer),
            Sharing::GridSnapshots { exchange, .. } => exchange.link_down(peer),
        }
    }

    /// What to send `peer` now within `budget` bytes (as encoded on the radio).
    pub fn outgoing(&mut self, peer: RobotId, budget: usize) -> Vec<Share> {
        match self {
            Sharing::RawScans { exchange, .. } => exchange
                .outgoing(peer, budget, |d| encode(d).len())
                .into_iter()
                .map(Share::Scans)
                .collect(),
            Sharing::Polygon { exchange, .. } => exchange
                .outgoing(peer, budget, |c| encode(c).len())
                .into_iter()
                .map(Share::Ops)
                .collect(),
            Sharing::GridSnapshots { exchange, .. } => exchange
                .outgoing(peer, budget, |d| encode(d).len())
                .into_iter()
                .map(Share::Patches)
                .collect(),
        }
    }

    /// Takes a received share; returns whether its sender should get a handshake (a gap).
    /// A share of the other mode, or one that cannot be taken, is `Err` with the reason.
    pub fn on_share(
        &mut self,
        s: &Share,
        map: &MapInfo,
        laser: &LaserSpec,
    ) -> Result<bool, String> {
        let outcome = match (self, s) {
            (
                Sharing::RawScans {
                    exchange,
                    others,
                    evidence,
                },
                Share::Scans(d),
            ) => {
                let first_new = exchange.log(d.owner).len();
                let outcome = exchange.on_delta(d);
                if matches!(outcome, DeltaOutcome::Appended { .. }) && d.owner != exchange.id() {
                    for rec in exchange.log(d.owner).get(first_new..).unwrap_or_default() {
                        let (pose, ranges) = scan_ranges(rec, laser);
                        evidence.integrate(others, map, pose, &ranges, laser);
                    }
                }
                outcome
            }
            (Sharing::Polygon { exchange, .. }, Share::Ops(c)) => {
                exchange.on_chunk(c).map_err(|e| e.to_string())?
            }
            (Sharing::GridSnapshots { exchange, others }, Share::Patches(d)) => {
                let first_new = exchange.log(d.owner).len();
                let outcome = exchange.on_delta(d);
                if matches!(outcome, DeltaOutcome::Appended { .. }) && d.owner != exchange.id() {
                    for p in exchange.log(d.owner).get(first_new..).unwrap_or_default() {
                        apply_patch(others, p).map_err(|e| e.to_string())?;
                    }
                }
                outcome
            }
            _ => return Err("a share of the other exchange mode".into()),
        };
        Ok(matches!(outcome, DeltaOutcome::Gap { .. }))
    }

    /// The planning grid: G_s with what peers shared filling its unknown cells — never
    /// overriding a cell this robot sensed itself.
    pub fn planning_grid(&self, own: &Grid) -> Grid {
        match self {
            Sharing::RawScans { others, .. } | Sharing::GridSnapshots { others, .. } => {
                let mut g = others.clone();
                for (p, &o) in g.cells_mut().iter_mut().zip(own.cells()) {
                    if o != Occ::Unknown {
                        *p = o;
                    }
                }
                g
            }
            Sharing::Polygon { exchange, .. } => {
                let peers: Vec<_> = exchange.approximations().map(|(_, a)| a).collect();
                merge(own, &peers)
            }
        }
    }

    /// Whether we hold log entries `peer` lacks (`false` before its handshake).
    pub fn has_pending(&self, peer: RobotId) -> bool {
        let lag = match self {
            Sharing::RawScans { exchange, .. } => exchange.lag(peer),
            Sharing::Polygon { exchange, .. } => exchange.lag(peer),
            Sharing::GridSnapshots { exchange, .. } => exchange.lag(peer),
        };
        lag.is_some_and(|n| n > 0)
    }

    /// What waits for `peer`: encoded bytes of the log entries we hold that it lacks (`None`
    /// before its handshake).
    pub fn backlog_bytes(&self, peer: RobotId) -> Option<u64> {
        match self {
            Sharing::RawScans { exchange, .. } => exchange.backlog(peer, |_, recs| {
                recs.iter().map(|r| encode(r).len() as u64).sum()
            }),
            Sharing::Polygon { exchange, .. } => exchange.backlog_bytes(peer),
            Sharing::GridSnapshots { exchange, .. } => exchange.backlog(peer, |_, recs| {
                recs.iter().map(|r| encode(r).len() as u64).sum()
            }),
        }
    }

    /// The end of a step's sending: the largest backlog of any neighbour (`None`: no
    /// neighbour) feeds the adaptive splitting control.
    pub fn after_sending(&mut self, largest_backlog: Option<u64>) {
        if let Sharing::Polygon { splitting, .. } = self {
            splitting.backlog(largest_backlog);
        }
    }

    /// The splitting frequency s for the next step (polygon mode).
    pub fn splits_per_step(&self) -> Option<f64> {
        match self {
            Sharing::Polygon { splitting, .. } => Some(splitting.current()),
            Sharing::RawScans { .. } | Sharing::GridSnapshots { .. } => None,
        }
    }

    /// Polygon mode: our own log length after the last save point and the digest of A_t there.
    pub fn own_save(&self) -> Option<(u32, u64)> {
        match self {
            Sharing::Polygon { mapper, .. } => Some((
                u32::try_from(mapper.log().len()).unwrap_or(u32::MAX),
                mapper.approximation().digest(),
            )),
            Sharing::RawScans { .. } | Sharing::GridSnapshots { .. } => None,
        }
    }

    /// Polygon mode: what we show of every other owner.
    pub fn views(&self) -> Vec<proto::msg::View> {
        match self {
            Sharing::Polygon { exchange, .. } => exchange.views(),
            Sharing::RawScans { .. } | Sharing::GridSnapshots { .. } => Vec::new(),
        }
    }

    /// e_avg of the own approximation so far (polygon mode, thesis eq. 6.1).
    pub fn approx_error_avg(&self) -> Option<f64> {
        match self {
            Sharing::Polygon { mapper, .. } => mapper.error_avg(),
            Sharing::RawScans { .. } | Sharing::GridSnapshots { .. } => None,
        }
    }
}
