//! Robot motion: checking a requested waypoint against the truth map and the other robots.
//!
//! docs/design.md §3: each step a robot asks for a waypoint within its speed along a collision-free
//! straight segment; the world-server moves it there or rejects the move "into obstacles or other
//! robots, and say why in the robot's next scan message"
//! ([`MoveOutcome`](proto::msg::MoveOutcome)). A waypoint beyond the step length is not an error:
//! the robot goes as far as it may in that direction, which is what a speed limit means. The
//! segment test is [`proto::traverse::swept`]: every cell the closed segment touches must be free,
//! including both side cells where it passes exactly through a corner, so a robot never slips
//! through a diagonal gap between two blocked cells (the reason free space is 4-connected in
//! [`crate::reachable`]). The robots' planner checks its waypoints with the same walk
//! (`robot_agent::nav::plan::next_waypoint`). Robots are points for the map and discs of
//! `robot_radius_m` for each other; the world-server looks for the robots a move ends near in a
//! [`Crowd`](crate::motion::Crowd) (buckets of the collision distance), so a step of n moves costs
//! O(n), not O(n²) — what a move costs grows with its length and the robots around its end, never
//! with the map or the team.

use std::collections::HashMap;

use proto::geom::{MapInfo, Metres, Pose};
use proto::grid::{Cell, Grid, Occ};
use proto::msg::{MoveOutcome, RobotId};
use proto::traverse::swept;

/// The robots a move is checked against.
pub trait Others {
    /// The robot nearest to `p` among those closer than `distance_m`, and where it is; of
    /// equally near ones, the first in id order.
    fn nearest(&self, p: Metres, distance_m: f64) -> Option<(RobotId, Metres)>;
}

/// Every robot in the slice, in its order.
impl Others for [(RobotId, Metres)] {
    fn nearest(&self, p: Metres, distance_m: f64) -> Option<(RobotId, Metres)> {
        self.iter()
            .map(|&(id, at)| (id, at, at.dist(p)))
            .filter(|&(_, _, d)| d < distance_m)
            .min_by(|a, b| a.2.total_cmp(&b.2))
            .map(|(id, at, _)| (id, at))
    }
}

/// The live robots of a team by position: a robot's index is its id, and it sits in the bucket
/// of side `Crowd::bucket_m` its position falls in, so the robots closer than that to a point
/// are in the 3 × 3 buckets around it.
#[derive(Clone, Debug)]
pub struct Crowd {
    bucket_m: f64,
    at: Vec<Option<Metres>>,
    buckets: HashMap<(i64, i64), Vec<RobotId>>,
}

impl Crowd {
    /// The robots at `at` (by id; `None`: not an obstacle, e.g. dead), for collision checks of
    /// up to `distance_m`.
    pub fn new(distance_m: f64, at: Vec<Option<Metres>>) -> Crowd {
        // A hair wider than the distance, so that rounding never puts two robots closer than it
        // two buckets apart.
        let bucket_m = if distance_m > 0.0 && distance_m.is_finite() {
            distance_m * (1.0 + 1e-6)
        } else {
            1.0
        };
        let mut crowd = Crowd {
            bucket_m,
            at: vec![None; at.len()],
            buckets: HashMap::new(),
        };
        for (id, p) in at.into_iter().enumerate() {
            crowd.place(id, p);
        }
        crowd
    }

    fn bucket(&self, p: Metres) -> (i64, i64) {
        // `as` saturates (and maps NaN to 0): any point has a bucket.
        (
            (p.x / self.bucket_m).floor() as i64,
            (p.y / self.bucket_m).floor() as i64,
        )
    }

    /// Robot `id` is now at `p` (`None`: no longer an obstacle).
    pub fn place(&mut self, id: usize, p: Option<Metres>) {
        let Some(slot) = self.at.get(id).copied() else {
            return;
        };
        if let Some(old) = slot {
            let key = self.bucket(old);
            if let Some(ids) = self.buckets.get_mut(&key) {
                ids.retain(|&r| usize::from(r) != id);
                if ids.is_empty() {
                    self.buckets.remove(&key);
                }
            }
        }
        self.at[id] = p;
        if let (Some(p), Ok(rid)) = (p, RobotId::try_from(id)) {
            let key = self.bucket(p);
            self.buckets.entry(key).or_default().push(rid);
        }
    }

    /// The crowd as robot `id` sees it: everyone but itself.
    pub fn without(&self, id: RobotId) -> Without<'_> {
        Without { crowd: self, id }
    }
}

/// A [`Crowd`] less one robot (the one that moves).
pub struct Without<'a> {
    crowd: &'a Crowd,
    id: RobotId,
}

impl Others for Without<'_> {
    fn nearest(&self, p: Metres, distance_m: f64) -> Option<(RobotId, Metres)> {
        let c = self.crowd;
        if distance_m > c.bucket_m {
            // Farther than the buckets reach: every robot, as a slice would be searched.
            let all: Vec<_> = (c.at.iter().enumerate())
                .filter_map(|(id, at)| Some((RobotId::try_from(id).ok()?, (*at)?)))
                .filter(|&(id, _)| id != self.id)
                .collect();
            return all.nearest(p, distance_m);
        }
        let (bx, by) = c.bucket(p);
        let mut near: Vec<(RobotId, Metres)> = (-1..=1)
            .flat_map(|dx| (-1..=1).map(move |dy| (bx.saturating_add(dx), by.saturating_add(dy))))
            .filter_map(|key| c.buckets.get(&key))
            .flatten()
            .filter(|&&id| id != self.id)
            .filter_map(|&id| Some((id, c.at.get(usize::from(id)).copied().flatten()?)))
            .collect();
        // In id order, as the whole team would be searched.
        near.sort_unstable_by_key(|&(id, _)| id);
        near.nearest(p, distance_m)
    }
}

/// Checks a move of a robot at `from` toward `to` (metres), clipped to `max_step_m`.
///
/// `others` are the positions of the *other* robots (the caller leaves the mover out). Returns
/// the new pose, heading along the motion, or why the robot stays: [`MoveOutcome::OutOfMap`]
/// (the end point, or the robot itself, lies outside the grid, or a coordinate is not finite),
/// [`MoveOutcome::Blocked`] (the segment touches a cell that is not free) or
/// [`MoveOutcome::Collision`] with (and at) the nearest robot whose position is closer than
/// `2 × robot_radius_m` to the end point. A move of length zero (or a zero step limit) returns
/// `from` unchanged, heading included.
pub fn validate_move(
    grid: &Grid,
    info: &MapInfo,
    from: Pose,
    to: Metres,
    max_step_m: f64,
    others: &[(RobotId, Metres)],
    robot_radius_m: f64,
) -> Result<Pose, MoveOutcome> {
    validate_move_among(grid, info, from, to, max_step_m, others, robot_radius_m)
}

/// [`validate_move`] against any [`Others`] (the world-server's [`Crowd`]).
pub fn validate_move_among(
    grid: &Grid,
    info: &MapInfo,
    from: Pose,
    to: Metres,
    max_step_m: f64,
    others: &(impl Others + ?Sized),
    robot_radius_m: f64,
) -> Result<Pose, MoveOutcome> {
    let finite = [from.x, from.y, to.x, to.y].iter().all(|v| v.is_finite());
    if !finite || !grid.contains(info.cell_of(from.xy())) {
        return Err(MoveOutcome::OutOfMap);
    }
    let (dx, dy) = (to.x - from.x, to.y - from.y);
    let length = dx.hypot(dy);
    // NaN or negative limits allow no motion at all.
    let step = if max_step_m > 0.0 { max_step_m } else { 0.0 };
    if length == 0.0 || step == 0.0 {
        return Ok(from);
    }
    let end = if length > step {
        Metres::new(from.x + dx / length * step, from.y + dy / length * step)
    } else {
        to
    };
    if !grid.contains(info.cell_of(end)) {
        return Err(MoveOutcome::OutOfMap);
    }
    if swept_m(info, from.xy(), end)
        .into_iter()
        .any(|c| grid.get(c) != Occ::Free)
    {
        return Err(MoveOutcome::Blocked);
    }
    if let Some((with, at)) = others.nearest(end, 2.0 * robot_radius_m) {
        let mm = |v: f64| (v * 1000.0).round() as i32;
        return Err(MoveOutcome::Collision {
            with,
            at_mm: (mm(at.x), mm(at.y)),
        });
    }
    Ok(Pose {
        x: end.x,
        y: end.y,
        theta: dy.atan2(dx),
    })
}

/// The cells a move between two metric points sweeps ([`proto::traverse::swept`], the walk the
/// planner checks its waypoints with).
pub fn swept_m(info: &MapInfo, a: Metres, b: Metres) -> Vec<Cell> {
    swept(info.in_cells(a), info.in_cells(b))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::f64::consts::FRAC_PI_2;

    const ROOM: &str = "
        ##########
        #........#
        #..#.....#
        #........#
        #.....?..#
        ##########";

    fn setup() -> (Grid, MapInfo) {
        let g = Grid::from_ascii(ROOM);
        let info = MapInfo::at_origin(g.width(), g.height(), 0.5);
        (g, info)
    }

    fn pose(x: f64, y: f64) -> Pose {
        Pose { x, y, theta: 0.3 }
    }

    #[test]
    fn a_free_move_heads_along_the_motion() {
        let (g, i) = setup();
        let got = validate_move(
            &g,
            &i,
            pose(0.75, 0.75),
            Metres::new(0.75, 1.75),
            2.0,
            &[],
            0.2,
        );
        assert_eq!(
            got,
            Ok(Pose {
                x: 0.75,
                y: 1.75,
                theta: FRAC_PI_2
            })
        );
    }

    #[test]
    fn long_moves_are_clipped_to_the_step() {
        let (g, i) = setup();
        let got = validate_move(
            &g,
            &i,
            pose(0.75, 0.75),
            Metres::new(3.75, 4.75),
            1.0,
            &[],
            0.2,
        )
        .expect("free segment");
        assert!(
            (got.x - 1.35).abs() < 1e-12 && (got.y - 1.55).abs() < 1e-12,
            "{got:?}"
        );
        assert!((got.theta - 4f64.atan2(3.0)).abs() < 1e-12);
    }

    #[test]
    fn zero_moves_keep_the_pose() {
        let (g, i) = setup();
        assert_eq!(
            validate_move(
                &g,
                &i,
                pose(0.75, 0.75),
                Metres::new(0.75, 0.75),
                1.0,
                &[],
                0.2
            ),
            Ok(pose(0.75, 0.75))
        );
        assert_eq!(
            validate_move(
                &g,
                &i,
                pose(0.75, 0.75),
                Metres::new(1.75, 0.75),
                0.0,
                &[],
                0.2
            ),
            Ok(pose(0.75, 0.75))
        );
        assert_eq!(
            validate_move(
                &g,
                &i,
                pose(0.75, 0.75),
                Metres::new(1.75, 0.75),
                f64::NAN,
                &[],
                0.2
            ),
            Ok(pose(0.75, 0.75))
        );
    }

    #[test]
    fn leaving_the_map_is_out_of_map() {
        let (g, i) = setup();
        assert_eq!(
            validate_move(
                &g,
                &i,
                pose(0.75, 0.75),
                Metres::new(-0.2, 0.75),
                5.0,
                &[],
                0.2
            ),
            Err(MoveOutcome::OutOfMap)
        );
        assert_eq!(
            validate_move(
                &g,
                &i,
                pose(0.75, 0.75),
                Metres::new(0.75, 3.0),
                5.0,
                &[],
                0.2
            ),
            Err(MoveOutcome::OutOfMap)
        );
        assert_eq!(
            validate_move(
                &g,
                &i,
                pose(0.75, 0.75),
                Metres::new(f64::NAN, 1.0),
                5.0,
                &[],
                0.2
            ),
            Err(MoveOutcome::OutOfMap)
        );
        assert_eq!(
            validate_move(
                &g,
                &i,
                pose(-9.0, 0.75),
                Metres::new(0.75, 0.75),
                5.0,
                &[],
                0.2
            ),
            Err(MoveOutcome::OutOfMap)
        );
        // Clipping can bring a target beyond the map back inside it: that move is legal.
        assert_eq!(
            validate_move(
                &g,
                &i,
                pose(0.75, 0.75),
                Metres::new(-5.0, 0.75),
                0.2,
                &[],
                0.2
            ),
            Ok(Pose {
                x: 0.55,
                y: 0.75,
                theta: std::f64::consts::PI
            })
        );
    }

    #[test]
    fn obstacles_unknown_cells_and_corners_block() {
        let (g, i) = setup();
        let blocked = |from: (f64, f64), to: (f64, f64)| {
            validate_move(
                &g,
                &i,
                pose(from.0, from.1),
                Metres::new(to.0, to.1),
                5.0,
                &[],
                0.2,
            )
        };
        assert_eq!(
            blocked((0.75, 1.75), (2.75, 1.75)),
            Err(MoveOutcome::Blocked),
            "through the pillar"
        );
        assert_eq!(
            blocked((2.75, 0.75), (3.75, 0.75)),
            Err(MoveOutcome::Blocked),
            "into the unknown cell"
        );
        assert_eq!(
            blocked((0.75, 0.75), (0.25, 0.75)),
            Err(MoveOutcome::Blocked),
            "into the wall"
        );
        // From cell (2,1) to cell (4,3): the segment passes exactly through the pillar's corner.
        assert_eq!(
            blocked((1.25, 0.75), (2.25, 1.75)),
            Err(MoveOutcome::Blocked),
            "touching a corner"
        );
        assert!(blocked((1.25, 0.75), (2.25, 0.75)).is_ok());
    }

    #[test]
    fn ending_near_another_robot_is_a_collision_with_the_nearest() {
        let (g, i) = setup();
        let others = [
            (3, Metres::new(2.2, 2.25)),
            (7, Metres::new(2.05, 2.25)),
            (9, Metres::new(4.0, 0.75)),
        ];
        let got = validate_move(
            &g,
            &i,
            pose(2.25, 1.25),
            Metres::new(2.25, 2.25),
            2.0,
            &others,
            0.2,
        );
        assert_eq!(
            got,
            Err(MoveOutcome::Collision {
                with: 3,
                at_mm: (2200, 2250)
            })
        );
        let touching = [(7, Metres::new(2.25, 2.75))];
        assert!(
            validate_move(
                &g,
                &i,
                pose(2.25, 1.25),
                Metres::new(2.25, 2.25),
                2.0,
                &touching,
                0.25
            )
            .is_ok(),
            "exactly 2r apart"
        );
    }

    proptest! {
        /// The crowd finds the robot the whole team's slice finds, whoever moves, dies or
        /// stands on a bucket's edge (positions on a 0.05 m lattice meet edges often).
        #[test]
        fn the_crowd_finds_what_the_whole_team_finds(
            start in prop::collection::vec(prop::option::weighted(0.9, (0u8..80, 0u8..80)), 1..40),
            moves in prop::collection::vec((0usize..40, prop::option::weighted(0.9, (0u8..80, 0u8..80))), 0..30),
            probes in prop::collection::vec((0u8..80, 0u8..80, 0usize..40), 1..20),
            radius in prop::sample::select(vec![0.1, 0.15, 0.2, 0.25]),
        ) {
            let m = |(x, y): (u8, u8)| Metres::new(f64::from(x) * 0.05, f64::from(y) * 0.05);
            let mut at: Vec<Option<Metres>> = start.iter().map(|p| p.map(m)).collect();
            let mut crowd = Crowd::new(2.0 * radius, at.clone());
            for (i, p) in moves {
                let i = i % at.len();
                at[i] = p.map(m);
                crowd.place(i, at[i]);
            }
            for (x, y, me) in probes {
                let me = (me % at.len()) as RobotId;
                let team: Vec<(RobotId, Metres)> = (at.iter().enumerate())
                    .filter_map(|(id, p)| Some((id as RobotId, (*p)?)))
                    .filter(|&(id, _)| id != me)
                    .collect();
                let p = m((x, y));
                prop_assert_eq!(
                    crowd.without(me).nearest(p, 2.0 * radius),
                    team.nearest(p, 2.0 * radius)
                );
            }
        }
    }
}
