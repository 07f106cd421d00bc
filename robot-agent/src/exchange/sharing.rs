//! What a robot shares over the radio and how its peers' shares become part of its planning
//! grid (docs/design.md §4.8; `exchange.mode`):
//!
//! * `raw-scans` — the baseline: every robot's laser scans, relayed transitively; received
//!   scans are integrated into a grid of the peers' knowledge (never overriding G_s).
//! * `polygon` — the thesis: every robot's op log of its incremental approximation A_t (Algorithm
//!   10 steps 2–6, [`crate::exchange::mapper`]), relayed transitively; the planning grid is merged
//!   from G_s and every peer's approximation at its last save point (Algorithm 9).
//!
//! * `grid-snapshots` — the second baseline: per step, the cells of G_s the scan changed,
//!   relayed transitively and written into a grid of the peers' knowledge (never overriding
//!   G_s).
//!
//! All speak the same handshake (`conn`) and budget rules; only the records differ. Each mode is
//! one implementation of [`Sharing`](crate::exchange::sharing::Sharing)
//! ([`RawScans`](crate::exchange::sharing::RawScans),
//! [`Polygon`](crate::exchange::sharing::Polygon),
//! [`GridSnapshots`](crate::exchange::sharing::GridSnapshots)), chosen by
//! [`new`](crate::exchange::sharing::new); what crosses the radio is a
//! [`Share`](crate::exchange::sharing::Share).

use proto::geom::{LaserSpec, MapInfo};
use proto::grid::{Cell, Grid, Occ, Rect};
use proto::msg::{
    decode, encode, DecodeError, Hello, OpChunk, PatchDelta, RobotId, Scan, ScanDelta, Traffic,
    WorldInfo,
};
use proto::scenario::{ExchangeMode, RadioModel, Scenario};

use crate::exchange::grid_snapshots::{apply_patch, patch_of, GridPatchExchange};
use crate::exchange::mapper::Mapper;
use crate::exchange::polygon::ApproxExchange;
use crate::exchange::raw_scans::{scan_ranges, scan_record, RawScanExchange};
use crate::exchange::splitting::{p_comm, SplittingFrequency};
use crate::exchange::transitive::{DeltaOutcome, Handshake, LogExchange};
use crate::mapping::grid::Evidence;
use crate::mapping::merge::{merge_into, Merger};

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

    /// Decodes a payload received under key segment `kind` (`None`: not a share's kind).
    pub fn decode(kind: &str, bytes: &[u8]) -> Option<Result<Share, DecodeError>> {
        match kind {
            "delta" => Some(decode(bytes).map(Share::Scans)),
            "ops" => Some(decode(bytes).map(Share::Ops)),
            "patch" => Some(decode(bytes).map(Share::Patches)),
            _ => None,
        }
    }

    /// The robot that sent it.
    pub fn from(&self) -> RobotId {
        match self {
            Share::Scans(d) => d.from,
            Share::Ops(c) => c.from,
            Share::Patches(d) => d.from,
        }
    }

    /// The radio key it is sent on, by addressee.
    pub fn key(&self) -> fn(RobotId) -> String {
        match self {
            Share::Scans(_) => proto::keys::radio_delta,
            Share::Ops(_) => proto::keys::radio_ops,
            Share::Patches(_) => proto::keys::radio_patch,
        }
    }

    /// Its `len` encoded bytes by package type: a scan delta's to `scan`, a patch delta's to
    /// `cells`; an op chunk's ops each to its package type and the chunk's header (ids, start
    /// index, count) to `conn`, the exchange's own overhead.
    pub fn by_type(&self, len: usize) -> Vec<(Traffic, usize)> {
        match self {
            Share::Scans(_) => vec![(Traffic::Scan, len)],
            Share::Patches(_) => vec![(Traffic::Cells, len)],
            Share::Ops(c) => {
                let mut out = crate::exchange::polygon::op_bytes(c);
                let ops: usize = out.iter().map(|&(_, n)| n).sum();
                out.push((Traffic::Conn, len.saturating_sub(ops)));
                out
            }
        }
    }
}

/// A robot's side of the exchange: what it shares, and how its peers' shares reach its
/// planning grid. One implementation per `exchange.mode`; the transitive log exchange with its
/// handshakes ([`crate::exchange::transitive`]) is common to all.
pub trait Sharing: Send {
    /// Records this step's own contribution (`changed`: the cells of `own`, G_s, the scan
    /// changed).
    fn after_scan(&mut self, scan: &Scan, laser: &LaserSpec, own: &Grid, changed: &[Cell]);

    /// The exchange's handshake side (`conn`), the same in every mode.
    fn handshake(&self) -> &dyn Handshake;
    fn handshake_mut(&mut self) -> &mut dyn Handshake;

    /// The knowledge vector (`conn`).
    fn knowledge(&self) -> Hello {
        self.handshake().knowledge()
    }

    fn on_hello(&mut self, h: &Hello) {
        self.handshake_mut().on_hello(h)
    }

    fn link_up(&mut self, peer: RobotId) {
        self.handshake_mut().link_up(peer)
    }

    fn link_down(&mut self, peer: RobotId) {
        self.handshake_mut().link_down(peer)
    }

    /// How many log entries we hold that `peer` lacks (`None` before its handshake).
    fn lag(&self, peer: RobotId) -> Option<u64> {
        self.handshake().lag(peer)
    }

    /// What to send `peer` now within `budget` bytes (as encoded on the radio).
    fn outgoing(&mut self, peer: RobotId, budget: usize) -> Vec<Share>;

    /// Takes a received share; returns whether its sender should get a handshake (a gap).
    /// A share of another mode, or one that cannot be taken, is `Err` with the reason.
    fn on_share(&mut self, s: &Share, map: &MapInfo, laser: &LaserSpec) -> Result<bool, String>;

    /// The planning grid: G_s with what peers shared filling its unknown cells — never
    /// overriding a cell this robot sensed itself.
    fn planning_grid(&self, own: &Grid) -> Grid {
        let mut out = Grid::new(own.width(), own.height(), Occ::Unknown);
        self.planning_grid_into(own, &mut out);
        out
    }

    /// [`Sharing::planning_grid`] written over `out`, the last one, in proportion to the
    /// explored part of the map (what G_s, the peers' shares and `out` know).
    fn planning_grid_into(&self, own: &Grid, out: &mut Grid);

    /// [`Sharing::planning_grid_into`] once a step, over the planning grid of the last call:
    /// a mode may keep what it computed and redo only what changed since (in G_s: the cells
    /// [`Sharing::after_scan`] was told of). Returns rectangles outside which no cell of `out`
    /// changed.
    fn update_planning_grid(&mut self, own: &Grid, out: &mut Grid) -> Vec<Rect> {
        self.planning_grid_into(own, out);
        out.whole().into_iter().collect()
    }

    /// What waits for `peer`: encoded bytes of the log entries we hold that it lacks (`None`
    /// before its handshake).
    fn backlog_bytes(&self, peer: RobotId) -> Option<u64>;

    /// Whether we hold log entries `peer` lacks (`false` before its handshake).
    fn has_pending(&self, peer: RobotId) -> bool {
        self.lag(peer).is_some_and(|n| n > 0)
    }

    /// The end of a step's sending: the largest backlog of any neighbour (`None`: no
    /// neighbour).
    fn after_sending(&mut self, _largest_backlog: Option<u64>) {}

    /// The splitting frequency s for the next step (polygon mode).
    fn splits_per_step(&self) -> Option<f64> {
        None
    }

    /// Polygon mode: our own log length after the last save point and the digest of A_t there.
    fn own_save(&self) -> Option<(u32, u64)> {
        None
    }

    /// Polygon mode: what we show of every other owner.
    fn views(&self) -> Vec<proto::msg::View> {
        Vec::new()
    }

    /// e_avg of the own approximation so far (polygon mode, thesis eq. 6.1).
    fn approx_error_avg(&self) -> Option<f64> {
        None
    }

    /// Polygon mode: per owner whose log we hold, the encoded bytes of its ops we hold.
    fn held_bytes(&self) -> Vec<(RobotId, u64)> {
        Vec::new()
    }

    /// Polygon mode: every approximation we hold — our own first, then each other owner's as
    /// we show it — for a viewer (never on the step's path).
    fn held(&self) -> Vec<proto::msg::HeldApprox> {
        Vec::new()
    }
}

/// Robot `me`'s sharing in scenario `s`'s exchange mode, in `world`, with a link budget of
/// `budget` bytes per step (`None`: unlimited).
pub fn new(
    s: &Scenario,
    me: RobotId,
    own: RobotId,
    world: &WorldInfo,
    budget: Option<f64>,
) -> Box<dyn Sharing> {
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
            let mut mapper = Mapper::new(splitting.current());
            mapper.edge_bounds = s.exchange.edge_bounds;
            Box::new(Polygon {
                exchange: ApproxExchange::owning(me, own).with_snapshots(s.exchange.snapshots),
                mapper: Box::new(mapper),
                splitting,
                merger: Merger::default(),
                own_changed: None,
            })
        }
        ExchangeMode::GridSnapshots => Box::new(GridSnapshots {
            exchange: GridPatchExchange::owning(me, own),
            others: empty,
        }),
        ExchangeMode::RawScans => Box::new(RawScans {
            exchange: RawScanExchange::owning(me, own),
            evidence: Evidence::new(&empty),
            others: empty,
        }),
    }
}

/// G_s with the cells it does not know taken from `others`, what peers told this robot,
/// written over `out` (the last one) where any of the three knows something.
fn overlay_into(others: &Grid, own: &Grid, out: &mut Grid) {
    let region = [
        others.known_bounds(),
        own.known_bounds(),
        out.known_bounds(),
    ]
    .into_iter()
    .fold(None, Rect::union_of);
    for c in region.into_iter().flat_map(Rect::cells) {
        let o = own.get(c);
        out.set(c, if o != Occ::Unknown { o } else { others.get(c) });
    }
}

/// Encoded bytes of the records we hold that `peer` lacks (`None` before its handshake).
fn encoded_backlog<R: Clone + serde::Serialize>(ex: &LogExchange<R>, peer: RobotId) -> Option<u64> {
    ex.backlog(peer, |_, recs| {
        recs.iter().map(|r| encode(r).len() as u64).sum()
    })
}

/// `raw-scans`: every robot's laser scans, relayed transitively; received scans are integrated
/// into a grid of the peers' knowledge.
pub struct RawScans {
    exchange: RawScanExchange,
    /// What peers' scans told this robot, and the beam counts behind it.
    others: Grid,
    evidence: Evidence,
}

impl Sharing for RawScans {
    fn after_scan(&mut self, scan: &Scan, laser: &LaserSpec, _own: &Grid, _changed: &[Cell]) {
        match scan_record(scan.step, scan.pose, &scan.ranges, laser) {
            Ok(rec) => self.exchange.record_own(rec),
            Err(e) => tracing::warn!("scan of step {} not shared: {e}", scan.step),
        }
    }

    fn handshake(&self) -> &dyn Handshake {
        &self.exchange
    }

    fn handshake_mut(&mut self) -> &mut dyn Handshake {
        &mut self.exchange
    }

    fn outgoing(&mut self, peer: RobotId, budget: usize) -> Vec<Share> {
        let out = self.exchange.outgoing(peer, budget, |d| encode(d).len());
        out.into_iter().map(Share::Scans).collect()
    }

    fn on_share(&mut self, s: &Share, map: &MapInfo, laser: &LaserSpec) -> Result<bool, String> {
        let Share::Scans(d) = s else {
            return Err("a share of another exchange mode".into());
        };
        let (outcome, new) = self.exchange.take_delta(d);
        for rec in new {
            let (pose, ranges) = scan_ranges(rec, laser);
            self.evidence
                .integrate(&mut self.others, map, pose, &ranges, laser);
        }
        Ok(matches!(outcome, DeltaOutcome::Gap { .. }))
    }

    fn planning_grid_into(&self, own: &Grid, out: &mut Grid) {
        overlay_into(&self.others, own, out);
    }

    fn backlog_bytes(&self, peer: RobotId) -> Option<u64> {
        encoded_backlog(&self.exchange, peer)
    }
}

/// `polygon`, the thesis: every robot's op log of its incremental approximation A_t, relayed
/// transitively; the planning grid is merged from G_s and every peer's approximation at its last
/// save point (Algorithm 9).
pub struct Polygon {
    exchange: ApproxExchange,
    mapper: Box<Mapper>,
    splitting: SplittingFrequency,
    /// The planning grid's painting of the peers' approximations, kept from step to step.
    merger: Merger,
    /// The cells of G_s changed since the planning grid was last updated.
    own_changed: Option<Rect>,
}

impl Sharing for Polygon {
    fn after_scan(&mut self, _scan: &Scan, _laser: &LaserSpec, own: &Grid, changed: &[Cell]) {
        let first = self.mapper.log().len();
        self.mapper.splits_per_step = self.splitting.current();
        let report = self.mapper.step(own, changed);
        self.splitting.record(report.splits, report.bytes);
        self.exchange.record_own(self.mapper.log().since(first));
        let changed = Rect::around(changed.iter().copied());
        self.own_changed = Rect::union_of(self.own_changed, changed);
    }

    fn handshake(&self) -> &dyn Handshake {
        &self.exchange
    }

    fn handshake_mut(&mut self) -> &mut dyn Handshake {
        &mut self.exchange
    }

    fn outgoing(&mut self, peer: RobotId, budget: usize) -> Vec<Share> {
        let out = self.exchange.outgoing(peer, budget, |c| encode(c).len());
        out.into_iter().map(Share::Ops).collect()
    }

    fn on_share(&mut self, s: &Share, _map: &MapInfo, _laser: &LaserSpec) -> Result<bool, String> {
        let Share::Ops(c) = s else {
            return Err("a share of another exchange mode".into());
        };
        let outcome = self.exchange.on_chunk(c).map_err(|e| e.to_string())?;
        Ok(matches!(outcome, DeltaOutcome::Gap { .. }))
    }

    fn planning_grid_into(&self, own: &Grid, out: &mut Grid) {
        let peers: Vec<_> = self.exchange.approximations().map(|(_, a)| a).collect();
        merge_into(out, own, &peers);
    }

    fn update_planning_grid(&mut self, own: &Grid, out: &mut Grid) -> Vec<Rect> {
        let peers: Vec<_> = self.exchange.approximations().collect();
        let own_changed = self.own_changed.take();
        self.merger.merge_into(out, own, own_changed, &peers)
    }

    fn backlog_bytes(&self, peer: RobotId) -> Option<u64> {
        self.exchange.backlog_bytes(peer)
    }

    /// The largest backlog feeds the adaptive splitting control.
    fn after_sending(&mut self, largest_backlog: Option<u64>) {
        self.splitting.backlog(largest_backlog);
    }

    fn splits_per_step(&self) -> Option<f64> {
        Some(self.splitting.current())
    }

    fn own_save(&self) -> Option<(u32, u64)> {
        Some((
            u32::try_from(self.mapper.log().len()).unwrap_or(u32::MAX),
            self.mapper.digest(),
        ))
    }

    fn views(&self) -> Vec<proto::msg::View> {
        self.exchange.views()
    }

    fn held_bytes(&self) -> Vec<(RobotId, u64)> {
        self.exchange.held_bytes()
    }

    fn held(&self) -> Vec<proto::msg::HeldApprox> {
        let own = u32::try_from(self.mapper.log().len()).unwrap_or(u32::MAX);
        let mut all = vec![proto::msg::HeldApprox {
            owner: self.exchange.own(),
            held: own,
            shown: own,
            polygons: self.mapper.approximation().outlines(),
        }];
        all.extend(
            self.exchange
                .shown()
                .map(|(owner, held, shown, a)| proto::msg::HeldApprox {
                    owner,
                    held,
                    shown,
                    polygons: a.outlines(),
                }),
        );
        all
    }

    fn approx_error_avg(&self) -> Option<f64> {
        self.mapper.error_avg()
    }
}

/// `grid-snapshots`: per step, the cells of G_s the scan changed, relayed transitively and
/// written into a grid of the peers' knowledge.
pub struct GridSnapshots {
    exchange: GridPatchExchange,
    /// What peers' patches told this robot.
    others: Grid,
}

impl Sharing for GridSnapshots {
    fn after_scan(&mut self, scan: &Scan, _laser: &LaserSpec, own: &Grid, changed: &[Cell]) {
        if !changed.is_empty() {
            self.exchange.record_own(patch_of(scan.step, own, changed));
        }
    }

    fn handshake(&self) -> &dyn Handshake {
        &self.exchange
    }

    fn handshake_mut(&mut self) -> &mut dyn Handshake {
        &mut self.exchange
    }

    fn outgoing(&mut self, peer: RobotId, budget: usize) -> Vec<Share> {
        let out = self.exchange.outgoing(peer, budget, |d| encode(d).len());
        out.into_iter().map(Share::Patches).collect()
    }

    fn on_share(&mut self, s: &Share, _map: &MapInfo, _laser: &LaserSpec) -> Result<bool, String> {
        let Share::Patches(d) = s else {
            return Err("a share of another exchange mode".into());
        };
        let (outcome, new) = self.exchange.take_delta(d);
        for p in new {
            apply_patch(&mut self.others, p).map_err(|e| e.to_string())?;
        }
        Ok(matches!(outcome, DeltaOutcome::Gap { .. }))
    }

    fn planning_grid_into(&self, own: &Grid, out: &mut Grid) {
        overlay_into(&self.others, own, out);
    }

    fn backlog_bytes(&self, peer: RobotId) -> Option<u64> {
        encoded_backlog(&self.exchange, peer)
    }
}
