//! The `raw-scans` baseline exchange (docs/design.md §4.8): the transitive log exchange of
//! [`crate::exchange::transitive`] carrying laser scans.
//!
//! This is the classic approach of Burgard et al. (paper 001) that the polygon exchange is
//! measured against, byte for byte: a scan record is a pose plus one quantized range per beam.

use proto::geom::{LaserSpec, Pose};
use proto::msg::{ScanRecord, Step};

use crate::exchange::transitive::LogExchange;

/// Every robot's scan log, exchanged transitively.
pub type RawScanExchange = LogExchange<ScanRecord>;

/// A scan that cannot be put on the radio as a [`ScanRecord`].
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum QuantizeError {
    #[error("pose ({x}, {y}, {theta}) is not finite")]
    NonFinitePose { x: f64, y: f64, theta: f64 },
    #[error("pose ({x} m, {y} m) lies beyond the ±2147 km a millimetre i32 can hold")]
    PoseOutOfRange { x: f64, y: f64 },
    #[error("maximum range {0} m exceeds the 655.34 m a centimetre u16 can hold")]
    MaxRangeTooLong(f64),
}

/// The largest range in centimetres a hit can carry; `u16::MAX` means no return.
const MAX_HIT_CM: u16 = u16::MAX - 1;

/// Quantizes a scan for the radio: pose to millimetres and milliradians (heading normalized to
/// [−π, π)), ranges to centimetres rounded to nearest, with `u16::MAX` for no return
/// (`≥ spec.max_range_m`). NaN and negative ranges become 0, which carries no information to
/// [`crate::mapping::grid::integrate_scan`] (a hit inside the robot's own cell is ignored).
pub fn scan_record(
    step: Step,
    pose: Pose,
    ranges: &[f32],
    spec: &LaserSpec,
) -> Result<ScanRecord, QuantizeError> {
    let Pose { x, y, theta } = pose;
    if !(x.is_finite() && y.is_finite() && theta.is_finite()) {
        return Err(QuantizeError::NonFinitePose { x, y, theta });
    }
    let mm = |v: f64| {
        let q = (v * 1000.0).round();
        (q >= f64::from(i32::MIN) && q <= f64::from(i32::MAX)).then_some(q as i32)
    };
    let (Some(x_mm), Some(y_mm)) = (mm(x), mm(y)) else {
        return Err(QuantizeError::PoseOutOfRange { x, y });
    };
    if spec.max_range_m.is_nan() || spec.max_range_m * 100.0 > f64::from(MAX_HIT_CM) {
        return Err(QuantizeError::MaxRangeTooLong(spec.max_range_m));
    }
    let heading =
        (theta + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
    let ranges_cm = ranges
        .iter()
        .map(|&r| {
            if f64::from(r) >= spec.max_range_m || r >= spec.max_range_m as f32 {
                u16::MAX
            } else if r.is_nan() || r <= 0.0 {
                0
            } else {
                (f64::from(r) * 100.0).round().min(f64::from(MAX_HIT_CM)) as u16
            }
        })
        .collect();
    Ok(ScanRecord {
        step,
        x_mm,
        y_mm,
        theta_mrad: (heading * 1000.0).round() as i32,
        ranges_cm,
    })
}

/// The pose and ranges of a received record, for [`crate::mapping::grid::integrate_scan`]: the inverse of
/// [`scan_record`] up to its rounding (½ mm, ½ mrad, ½ cm). No return comes back as the smallest
/// `f32` not below `spec.max_range_m`, and a hit never comes back at or beyond it.
pub fn scan_ranges(rec: &ScanRecord, spec: &LaserSpec) -> (Pose, Vec<f32>) {
    let pose = Pose {
        x: f64::from(rec.x_mm) / 1000.0,
        y: f64::from(rec.y_mm) / 1000.0,
        theta: f64::from(rec.theta_mrad) / 1000.0,
    };
    let no_return = f32_at_least(spec.max_range_m);
    let below_max = f32_below(spec.max_range_m);
    let ranges = rec
        .ranges_cm
        .iter()
        .map(|&cm| match cm {
            u16::MAX => no_return,
            cm => {
                let r = f32::from(cm) / 100.0;
                if f64::from(r) >= spec.max_range_m {
                    below_max
                } else {
                    r
                }
            }
        })
        .collect();
    (pose, ranges)
}

/// The smallest `f32` that is `≥ v` (for a positive, finite `v`; otherwise `v as f32`).
fn f32_at_least(v: f64) -> f32 {
    let f = v as f32;
    if f64::from(f) < v && f.is_finite() && f > 0.0 {
        f32::from_bits(f.to_bits() + 1)
    } else {
        f
    }
}

/// The largest `f32` that is `< v` (for a positive, finite `v`; otherwise `v as f32`).
fn f32_below(v: f64) -> f32 {
    let f = v as f32;
    if f64::from(f) >= v && f.is_finite() && f > 0.0 {
        f32::from_bits(f.to_bits() - 1)
    } else {
        f
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::exchange::transitive::{DeltaOutcome, Handshake};
    use crate::mapping::grid::box_world::box_range;
    use crate::mapping::grid::integrate_scan;
    use proptest::prelude::*;
    use proto::geom::MapInfo;
    use proto::grid::{Grid, Occ};
    use proto::msg::encode;
    use proto::msg::{Hello, RobotId, ScanDelta};
    use std::collections::BTreeSet;
    use std::f64::consts::TAU;
    use std::ops::Range;

    /// A recognizable record: `owner`'s `index`-th scan, with a few ranges so sizes vary.
    fn rec(owner: RobotId, index: u32) -> ScanRecord {
        ScanRecord {
            step: index,
            x_mm: i32::from(owner),
            y_mm: 0,
            theta_mrad: 0,
            ranges_cm: vec![index as u16; 1 + (index as usize % 5)],
        }
    }

    fn delta(from: RobotId, owner: RobotId, range: Range<u32>) -> ScanDelta {
        ScanDelta {
            from,
            owner,
            start: range.start,
            records: range.map(|i| rec(owner, i)).collect(),
        }
    }

    fn wire_size(d: &ScanDelta) -> usize {
        encode(d).len()
    }

    fn hello(from: RobotId, knowledge: &[(RobotId, u32)]) -> Hello {
        Hello {
            from,
            knowledge: knowledge.to_vec(),
            reset: true,
        }
    }

    /// Robot `me` holding `counts[owner]` records of each listed owner's log.
    fn holding(me: RobotId, counts: &[(RobotId, u32)]) -> RawScanExchange {
        let mut x = RawScanExchange::new(me);
        for &(owner, n) in counts {
            if owner == me {
                (0..n).for_each(|i| x.record_own(rec(me, i)));
            } else {
                let _ = x.on_delta(&delta(owner, owner, 0..n));
            }
        }
        x
    }

    /// The (owner, start, len) of each delta, for compact comparisons.
    fn shape(ds: &[ScanDelta]) -> Vec<(RobotId, u32, usize)> {
        ds.iter()
            .map(|d| (d.owner, d.start, d.records.len()))
            .collect()
    }

    #[test]
    fn gap_is_reported_and_nothing_appended() {
        let mut x = RawScanExchange::new(1);
        assert_eq!(
            x.on_delta(&delta(0, 0, 2..3)),
            DeltaOutcome::Gap {
                owner: 0,
                have: 0,
                start: 2
            }
        );
        assert!(x.log(0).is_empty());
        assert_eq!(
            x.knowledge(),
            hello(1, &[(0, 0), (1, 0)]),
            "the reply handshake says 0"
        );
    }

    #[test]
    fn duplicates_are_ignored_and_overlaps_append_only_the_tail() {
        let mut x = RawScanExchange::new(1);
        assert_eq!(
            x.on_delta(&delta(0, 0, 0..3)),
            DeltaOutcome::Appended {
                owner: 0,
                new: 0..3
            }
        );
        assert_eq!(
            x.on_delta(&delta(2, 0, 1..5)),
            DeltaOutcome::Appended {
                owner: 0,
                new: 3..5
            }
        );
        assert_eq!(x.on_delta(&delta(0, 0, 0..2)), DeltaOutcome::Duplicate);
        assert_eq!(
            x.on_delta(&delta(0, 0, 5..5)),
            DeltaOutcome::Duplicate,
            "empty delta"
        );
        let want: Vec<ScanRecord> = (0..5).map(|i| rec(0, i)).collect();
        assert_eq!(x.log(0), want.as_slice());
    }

    #[test]
    fn nothing_is_sent_before_the_handshake() {
        let mut x = holding(1, &[(1, 3)]);
        assert!(x.outgoing(2, usize::MAX, wire_size).is_empty());
        assert_eq!(x.lag(2), None);
        x.link_up(2);
        assert!(x.outgoing(2, usize::MAX, wire_size).is_empty());
        x.on_hello(&hello(2, &[]));
        assert_eq!(x.lag(2), Some(3));
        assert_eq!(shape(&x.outgoing(2, usize::MAX, wire_size)), [(1, 0, 3)]);
        assert_eq!(x.lag(2), Some(0), "S is raised optimistically");
        assert!(x.outgoing(2, usize::MAX, wire_size).is_empty());
        x.link_down(2);
        assert!(
            x.outgoing(2, usize::MAX, wire_size).is_empty(),
            "S forgotten with the link"
        );
        x.link_up(2);
        x.on_hello(&hello(2, &[(1, 1)]));
        assert_eq!(
            shape(&x.outgoing(2, usize::MAX, wire_size)),
            [(1, 1, 2)],
            "resume at 1"
        );
    }

    #[test]
    fn handshake_replaces_the_optimistic_belief() {
        let mut x = holding(1, &[(1, 4)]);
        x.on_hello(&hello(2, &[]));
        assert_eq!(x.outgoing(2, usize::MAX, wire_size).len(), 1);
        // The peer says it got only 2: those in flight were lost.
        x.on_hello(&hello(2, &[(1, 2), (0, 7)]));
        assert_eq!(shape(&x.outgoing(2, usize::MAX, wire_size)), [(1, 2, 2)]);
    }

    #[test]
    fn received_records_are_not_sent_back() {
        let mut x = RawScanExchange::new(1);
        x.on_hello(&hello(2, &[]));
        x.on_hello(&hello(3, &[]));
        let _ = x.on_delta(&delta(2, 0, 0..3));
        assert_eq!(x.lag(2), Some(0), "the sender holds what it sent");
        assert_eq!(
            shape(&x.outgoing(3, usize::MAX, wire_size)),
            [(0, 0, 3)],
            "relayed onwards"
        );
    }

    #[test]
    fn policy_order_is_largest_lag_then_own_then_lowest_id() {
        let mut x = holding(1, &[(0, 3), (1, 3), (2, 5), (4, 3)]);
        x.on_hello(&hello(3, &[(4, 1)]));
        let out = x.outgoing(3, usize::MAX, wire_size);
        assert_eq!(shape(&out), [(2, 0, 5), (1, 0, 3), (0, 0, 3), (4, 1, 2)]);
    }

    #[test]
    fn budget_is_respected() {
        let mut x = holding(1, &[(1, 4), (0, 4)]);
        x.on_hello(&hello(2, &[]));
        let one = wire_size(&delta(1, 1, 0..1));
        let two = wire_size(&delta(1, 1, 0..2));
        // A record larger than the budget blocks the call.
        assert!(x.outgoing(2, one - 1, wire_size).is_empty());
        assert_eq!(x.lag(2), Some(8), "nothing sent, nothing assumed");
        // Exactly two records' worth.
        let out = x.outgoing(2, two, wire_size);
        assert_eq!(shape(&out), [(1, 0, 2)]);
        // The budget spans owners, and never is exceeded.
        for budget in [0, 10, 50, 100, 200, 400] {
            let mut y = holding(1, &[(1, 4), (0, 4)]);
            y.on_hello(&hello(2, &[]));
            let out = y.outgoing(2, budget, wire_size);
            assert!(out.iter().map(wire_size).sum::<usize>() <= budget);
        }
        let mut y = holding(1, &[(1, 4), (0, 4)]);
        y.on_hello(&hello(2, &[]));
        let all = wire_size(&delta(1, 1, 0..4)) + wire_size(&delta(1, 0, 0..4));
        assert_eq!(
            shape(&y.outgoing(2, all, wire_size)),
            [(1, 0, 4), (0, 0, 4)]
        );
    }

    #[test]
    fn quantization_round_trips_within_its_rounding() {
        let spec = LaserSpec {
            beams: 6,
            fov_rad: TAU,
            max_range_m: 8.0,
            noise_std_m: 0.0,
        };
        let pose = Pose {
            x: -12.3456,
            y: 7.0004,
            theta: 3.5,
        };
        let ranges = [0.123, 7.996, 8.0, f32::INFINITY, f32::NAN, -0.5];
        let r = scan_record(9, pose, &ranges, &spec).expect("quantizable");
        assert_eq!(r.x_mm, -12346);
        assert_eq!(r.y_mm, 7000);
        assert_eq!(r.theta_mrad, ((3.5 - TAU) * 1000.0_f64).round() as i32);
        assert_eq!(r.ranges_cm, [12, 800, u16::MAX, u16::MAX, 0, 0]);
        let (back, got) = scan_ranges(&r, &spec);
        assert!((back.x - pose.x).abs() <= 0.0005 && (back.y - pose.y).abs() <= 0.0005);
        assert!((back.theta - (pose.theta - TAU)).abs() <= 0.0005);
        assert_eq!(got[0], 0.12);
        assert!(
            f64::from(got[1]) < 8.0,
            "a hit near the maximum stays a hit"
        );
        assert!(
            f64::from(got[2]) >= 8.0 && f64::from(got[3]) >= 8.0,
            "no return stays no return"
        );
        assert_eq!(&got[4..], [0.0, 0.0]);
    }

    #[test]
    fn unquantizable_scans_are_errors() {
        let spec = LaserSpec {
            beams: 1,
            fov_rad: 0.0,
            max_range_m: 8.0,
            noise_std_m: 0.0,
        };
        let nan = Pose {
            x: f64::NAN,
            y: 0.0,
            theta: 0.0,
        };
        assert!(matches!(
            scan_record(0, nan, &[], &spec),
            Err(QuantizeError::NonFinitePose { .. })
        ));
        let far = Pose {
            x: 3e6,
            y: 0.0,
            theta: 0.0,
        };
        assert!(matches!(
            scan_record(0, far, &[], &spec),
            Err(QuantizeError::PoseOutOfRange { .. })
        ));
        let long = LaserSpec {
            max_range_m: 700.0,
            ..spec
        };
        assert_eq!(
            scan_record(0, Pose::default(), &[], &long),
            Err(QuantizeError::MaxRangeTooLong(700.0))
        );
    }

    /// One round of the simulated radio for up to five robots (ten pairs).
    #[derive(Clone, Debug)]
    struct Round {
        /// Bit p: pair p is linked this round.
        links: u16,
        /// Bit r: robot r records a scan.
        records: u8,
        /// Bit p: pair p exchanges a periodic handshake.
        hellos: u16,
        /// Per pair: bit k % 8 drops the pair's k-th message this round (in the cuts-only mode,
        /// only if the link is cut after this round).
        drops: Vec<u8>,
        budget_bytes: usize,
    }

    fn arb_round() -> impl Strategy<Value = Round> {
        let drop = (any::<u8>(), 0u8..4).prop_map(|(p, k)| if k == 0 { p } else { 0 });
        (
            any::<u16>(),
            any::<u8>(),
            (any::<u16>(), any::<u16>(), any::<u16>()).prop_map(|(a, b, c)| a & b & c),
            proptest::collection::vec(drop, 10),
            0usize..300,
        )
            .prop_map(|(links, records, hellos, drops, budget_bytes)| Round {
                links,
                records,
                hellos,
                drops,
                budget_bytes,
            })
    }

    /// The robots and what the test knows about them.
    struct Sim {
        robots: Vec<RawScanExchange>,
        pairs: Vec<(usize, usize)>,
        up: BTreeSet<usize>,
        /// Messages get lost only when a link is cut (what was in flight), not on a live link.
        cuts_only: bool,
    }

    impl Sim {
        fn new(n: usize, cuts_only: bool) -> Sim {
            let pairs = (0..n)
                .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
                .collect();
            let robots = (0..n).map(|i| RawScanExchange::new(i as RobotId)).collect();
            Sim {
                robots,
                pairs,
                up: BTreeSet::new(),
                cuts_only,
            }
        }

        /// The true log of `owner`: its own.
        fn truth(&self, owner: usize) -> &[ScanRecord] {
            self.robots[owner].log(owner as RobotId)
        }

        /// Every robot holds a prefix of every owner's true log.
        fn check_prefixes(&self) -> Result<(), TestCaseError> {
            for r in &self.robots {
                for owner in r.owners() {
                    let held = r.log(owner);
                    let truth = self.truth(usize::from(owner));
                    prop_assert!(held.len() <= truth.len() && held == &truth[..held.len()]);
                }
            }
            Ok(())
        }

        fn send_hello(&mut self, from: usize, to: usize, dropped: bool) {
            if !dropped {
                let h = self.robots[from].knowledge();
                self.robots[to].on_hello(&h);
            }
        }

        /// Both directions of pair `p`; returns how many deltas were sent.
        fn exchange(&mut self, p: usize, budget: usize, drops: u8) -> Result<usize, TestCaseError> {
            let (i, j) = self.pairs[p];
            let mut k = 0u32;
            let mut dropped = || {
                k += 1;
                drops & (1 << ((k - 1) % 8)) != 0
            };
            let mut sent = 0;
            for (a, b) in [(i, j), (j, i)] {
                let deltas = self.robots[a].outgoing(b as RobotId, budget, wire_size);
                prop_assert!(deltas.iter().map(wire_size).sum::<usize>() <= budget);
                sent += deltas.len();
                for d in deltas {
                    if dropped() {
                        continue;
                    }
                    let before = self.robots[b].log(d.owner).len() as u32;
                    let outcome = self.robots[b].on_delta(&d);
                    let after = self.robots[b].log(d.owner).len() as u32;
                    match outcome {
                        DeltaOutcome::Appended { owner, new } => {
                            prop_assert_eq!(owner, d.owner);
                            prop_assert_eq!(new, before..after);
                            prop_assert!(after > before);
                        }
                        DeltaOutcome::Duplicate => prop_assert_eq!(after, before),
                        DeltaOutcome::Gap { .. } => {
                            prop_assert_eq!(after, before);
                            let lost = dropped();
                            self.send_hello(b, a, lost);
                        }
                        DeltaOutcome::Arriving { .. } | DeltaOutcome::Installed { .. } => {
                            prop_assert!(false, "scan logs have no snapshots: {:?}", outcome);
                        }
                    }
                    self.check_prefixes()?;
                }
            }
            Ok(sent)
        }

        /// Plays round `r`; `next_links` are the links of the round after it. Returns how many
        /// deltas were sent.
        fn round(&mut self, r: &Round, next_links: u16) -> Result<usize, TestCaseError> {
            let drops: Vec<u8> = (0..self.pairs.len())
                .map(|p| {
                    let cut_next = next_links & (1 << p) == 0;
                    if self.cuts_only && !cut_next {
                        0
                    } else {
                        r.drops[p]
                    }
                })
                .collect();
            for (p, &(i, j)) in self.pairs.clone().iter().enumerate() {
                let now = r.links & (1 << p) != 0;
                let was = self.up.contains(&p);
                if now && !was {
                    self.robots[i].link_up(j as RobotId);
                    self.robots[j].link_up(i as RobotId);
                    self.send_hello(i, j, drops[p] & 1 != 0);
                    self.send_hello(j, i, drops[p] & 2 != 0);
                    self.up.insert(p);
                } else if !now && was {
                    self.robots[i].link_down(j as RobotId);
                    self.robots[j].link_down(i as RobotId);
                    self.up.remove(&p);
                }
            }
            for (k, robot) in self.robots.iter_mut().enumerate() {
                if r.records & (1 << k) != 0 {
                    let index = robot.log(k as RobotId).len() as u32;
                    robot.record_own(rec(k as RobotId, index));
                }
            }
            let up: Vec<usize> = self.up.iter().copied().collect();
            let mut sent = 0;
            for p in up {
                let (i, j) = self.pairs[p];
                if r.hellos & (1 << p) != 0 {
                    self.send_hello(i, j, false);
                    self.send_hello(j, i, false);
                }
                sent += self.exchange(p, r.budget_bytes, drops[p])?;
            }
            Ok(sent)
        }
    }

    /// The world-server's ranges for a robot at `p` (cells) inside a `w × h` box of 0.1 m cells
    /// whose ring of border cells is wall.
    fn box_ranges(p: (f64, f64), theta: f64, w: i32, h: i32, spec: &LaserSpec) -> Vec<f32> {
        (0..spec.beams)
            .map(|i| box_range(p, theta + spec.beam_angle(i), w, h, 0.1, spec.max_range_m))
            .collect()
    }

    proptest! {
        /// A received record integrates almost like the scan it came from: centimetre ranges
        /// move a hit to a neighbouring cell only where two cell borders cross the beam within
        /// the rounding, a few cells per scan.
        #[test]
        fn received_records_integrate_nearly_like_the_scan(
            px in 1.0f64..59.0,
            py in 1.0f64..39.0,
            theta in -3.2f64..3.2,
        ) {
            let (w, h) = (60, 40);
            let info = MapInfo::at_origin(w as u32, h as u32, 0.1);
            let spec = LaserSpec { beams: 360, fov_rad: TAU, max_range_m: 8.0, noise_std_m: 0.0 };
            let pose = Pose { x: px * 0.1, y: py * 0.1, theta };
            let ranges = box_ranges((px, py), theta, w, h, &spec);
            let mut direct = Grid::new(w as u32, h as u32, Occ::Unknown);
            integrate_scan(&mut direct, &info, pose, &ranges, &spec);
            let record = scan_record(0, pose, &ranges, &spec).expect("quantizable");
            let (pose2, ranges2) = scan_ranges(&record, &spec);
            let mut received = Grid::new(w as u32, h as u32, Occ::Unknown);
            integrate_scan(&mut received, &info, pose2, &ranges2, &spec);
            let differ = direct.cells().iter().zip(received.cells()).filter(|(a, b)| a != b).count();
            let known = direct.len() - direct.count(Occ::Unknown);
            prop_assert!(differ * 50 <= known, "{} of {} known cells differ", differ, known);
        }

        #[test]
        fn logs_converge_after_full_contact(
            n in 2usize..=5,
            chaos in proptest::collection::vec(arb_round(), 0..40),
            final_budget in 100usize..400,
            cuts_only in any::<bool>(),
        ) {
            let mut sim = Sim::new(n, cuts_only);
            for (k, r) in chaos.iter().enumerate() {
                sim.round(r, chaos.get(k + 1).map_or(u16::MAX, |next| next.links))?;
            }
            // Everyone meets everyone with no losses. On lossy live links only a periodic
            // handshake can reveal a lost tail, so that mode gets one on every link; when losses
            // come only with cuts, the handshakes at link-up must suffice.
            let calm = Round {
                links: u16::MAX,
                records: 0,
                hellos: if cuts_only { 0 } else { u16::MAX },
                drops: vec![0; 10],
                budget_bytes: final_budget,
            };
            sim.round(&calm, u16::MAX)?;
            let quiet = Round { hellos: 0, ..calm };
            let mut rounds = 0;
            while sim.round(&quiet, u16::MAX)? > 0 {
                rounds += 1;
                prop_assert!(rounds < 1000, "no convergence");
            }
            for r in &sim.robots {
                for owner in 0..n {
                    prop_assert_eq!(r.log(owner as RobotId), sim.truth(owner));
                }
                for peer in 0..n {
                    if peer != usize::from(r.id()) {
                        prop_assert_eq!(r.lag(peer as RobotId), Some(0));
                    }
                }
            }
        }
    }
}
