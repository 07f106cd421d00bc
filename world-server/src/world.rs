//! The simulated world's state and its step: truth map, reachable region, robot bodies,
//! laser scans and moves (docs/design.md §3). Pure: the zenoh side lives in [`crate::server`].
//!
//! **Invariant:** the world-server alone owns ground truth; robots learn the world only through
//! the scans this module casts.

use std::collections::HashMap;

use proto::geom::{LaserSpec, MapInfo, Metres, Pose};
use proto::grid::Grid;
use proto::msg::{Cmd, MoveOutcome, RobotId, RobotStatus, Scan, Status, Step, TruthMap, WorldInfo};
use proto::scenario::Scenario;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::generate::{generate, GenError};
use crate::map::{resample, MapError};
use crate::motion::Crowd;
use crate::reachable::{reachable_free, spawn_cluster, SpawnError};
use crate::shipped::MapSource;
use proto::scenario::GeneratedWorld;

/// Why a world could not be built.
#[derive(Debug, thiserror::Error)]
pub enum WorldError {
    #[error(transparent)]
    Map(#[from] MapError),
    #[error(transparent)]
    Spawn(#[from] SpawnError),
    #[error(transparent)]
    Generate(#[from] GenError),
    #[error("world.map = {0:?} is a file path but the scenario gave no file to load")]
    NoMapFile(String),
    #[error("base_station.pose = [{0}, {1}] lies outside the map")]
    BaseOutside(f64, f64),
}

/// The base station: a radio node that neither moves nor senses (node id `robots.count`). The
/// world only ticks it — a scan without beams each step — so that it keeps step with the
/// robots, and reports where it stands (netem's radio models need it).
#[derive(Clone, Debug)]
pub struct Base {
    pub id: RobotId,
    pub pose: Pose,
    pub alive: bool,
}

/// One robot's body.
#[derive(Clone, Debug)]
pub struct Body {
    pub id: RobotId,
    pub pose: Pose,
    pub alive: bool,
    /// Consecutive steps without a command (lockstep dead-robot detection).
    pub missed: u32,
    pub distance_m: f64,
    pub last_move: MoveOutcome,
}

pub struct World {
    pub truth: crate::map::TruthMap,
    /// Free cells 4-connected to the spawn area: what exploration must cover.
    pub reachable: Grid,
    pub bodies: Vec<Body>,
    pub base: Option<Base>,
    laser: LaserSpec,
    max_step_m: f64,
    radius_m: f64,
    dead_after: u32,
    step_seconds: f64,
    speed_m_per_s: f64,
    rng: ChaCha8Rng,
    collisions_total: u64,
    blocked_total: u64,
    /// Dead nodes that showed life again (a restarted process's token, a thawed one's
    /// command): alive again from the next step.
    rejoining: std::collections::BTreeSet<RobotId>,
}

impl World {
    /// Builds the world of a scenario: loads (`map`: a file or a carried map) or generates the truth, resamples it to
    /// `world.resolution_m`, places the robots and computes the reachable region from them.
    pub fn build(s: &Scenario, map: Option<&MapSource>) -> Result<World, WorldError> {
        let truth = match s.world.map.as_str() {
            name if s.world_is_generated() => {
                let kind: GeneratedWorld = name.parse().map_err(GenError::UnknownKind)?;
                generate(
                    kind,
                    s.world.width_m,
                    s.world.height_m,
                    s.world.resolution_m,
                    s.seed,
                )?
            }
            other => {
                let source = map.ok_or_else(|| WorldError::NoMapFile(other.into()))?;
                resample(&source.load()?, s.world.resolution_m)?
            }
        };
        let spawn = spawn_cluster(
            &truth.grid,
            &truth.info,
            usize::from(s.robots.count),
            s.robots.spawn_spacing_m,
            s.robots.spawn_clearance_m,
            s.seed,
        )?;
        let reachable = reachable_free(&truth.grid, &spawn);
        let bodies = spawn
            .iter()
            .enumerate()
            .map(|(i, &c)| {
                let Metres { x, y } = truth.info.centre_of(c);
                Body {
                    id: i as RobotId,
                    pose: Pose { x, y, theta: 0.0 },
                    alive: true,
                    missed: 0,
                    distance_m: 0.0,
                    last_move: MoveOutcome::Start,
                }
            })
            .collect();
        let base = match (s.base_id(), s.base_station.pose) {
            (None, _) => None,
            (Some(id), Some([x, y])) => {
                if !truth.grid.contains(truth.info.cell_of(Metres::new(x, y))) {
                    return Err(WorldError::BaseOutside(x, y));
                }
                Some(Base {
                    id,
                    pose: Pose { x, y, theta: 0.0 },
                    alive: true,
                })
            }
            // In the spawn area: where robot 0 starts (the spawn cluster's anchor).
            (Some(id), None) => {
                let Metres { x, y } = truth.info.centre_of(spawn[0]);
                Some(Base {
                    id,
                    pose: Pose { x, y, theta: 0.0 },
                    alive: true,
                })
            }
        };
        Ok(World {
            truth,
            reachable,
            bodies,
            base,
            laser: s.laser(),
            max_step_m: s.robots.speed_m_per_s * s.clock.step_seconds,
            radius_m: s.robots.radius_m,
            dead_after: s.clock.dead_after,
            step_seconds: s.clock.step_seconds,
            speed_m_per_s: s.robots.speed_m_per_s,
            rng: ChaCha8Rng::seed_from_u64(s.seed ^ 0x5eed_1a5e),
            collisions_total: 0,
            blocked_total: 0,
            rejoining: Default::default(),
        })
    }

    pub fn map(&self) -> MapInfo {
        self.truth.info
    }

    pub fn info(&self) -> WorldInfo {
        WorldInfo {
            map: self.truth.info,
            laser: self.laser,
            step_seconds: self.step_seconds,
            robots: self.bodies.len() as u16,
            max_speed_m_per_s: self.speed_m_per_s,
        }
    }

    pub fn truth_msg(&self) -> TruthMap {
        TruthMap {
            map: self.truth.info,
            grid_rle: self.truth.grid.to_rle(),
            reachable_rle: self.reachable.to_rle(),
        }
    }

    /// The base station's tick of `step`: a scan without beams at its pose (`None`: no base
    /// station, or it is gone).
    pub fn base_tick(&self, step: Step) -> Option<(RobotId, Scan)> {
        let b = self.base.as_ref().filter(|b| b.alive)?;
        Some((
            b.id,
            Scan {
                step,
                pose: b.pose,
                ranges: Vec::new(),
                last_move: MoveOutcome::Stayed,
            },
        ))
    }

    /// The scan robot `id` receives at `step` (its pose after the previous step's moves).
    pub fn scan(&mut self, id: RobotId, step: Step) -> Option<Scan> {
        let body = self.bodies.get(usize::from(id))?.clone();
        let noisy = self.laser.noise_std_m > 0.0;
        let ranges = crate::laser::cast(
            &self.truth.grid,
            &self.truth.info,
            body.pose,
            &self.laser,
            if noisy {
                Some(&mut self.rng as &mut dyn rand::RngCore)
            } else {
                None
            },
        );
        Some(Scan {
            step,
            pose: body.pose,
            ranges,
            last_move: body.last_move,
        })
    }

    /// Applies the commands of one step in robot-id order (deterministic): each valid move
    /// happens, every other robot stays and learns why in its next scan. Live robots without a
    /// command count a miss; after `dead_after` misses in a row they are declared dead.
    pub fn apply(&mut self, step: Step, cmds: &HashMap<RobotId, Cmd>) {
        // Where the live robots are, kept up to date move by move (a robot moved earlier in the
        // step is an obstacle where it now stands).
        let mut crowd = Crowd::new(
            2.0 * self.radius_m,
            (self.bodies.iter())
                .map(|b| b.alive.then_some(b.pose.xy()))
                .collect(),
        );
        for i in 0..self.bodies.len() {
            if !self.bodies[i].alive {
                continue;
            }
            let id = self.bodies[i].id;
            let outcome = match cmds.get(&id) {
                None => {
                    self.bodies[i].missed += 1;
                    if self.bodies[i].missed >= self.dead_after {
                        self.bodies[i].alive = false;
                        crowd.place(i, None);
                    }
                    MoveOutcome::Missed
                }
                Some(cmd) if cmd.step != step => MoveOutcome::WrongStep,
                Some(Cmd { waypoint: None, .. }) => MoveOutcome::Stayed,
                Some(Cmd {
                    waypoint: Some(to), ..
                }) => self.try_move(i, *to, &mut crowd),
            };
            if cmds.contains_key(&id) {
                self.bodies[i].missed = 0;
            }
            match outcome {
                MoveOutcome::Collision { .. } => self.collisions_total += 1,
                MoveOutcome::Blocked => self.blocked_total += 1,
                _ => {}
            }
            self.bodies[i].last_move = outcome;
        }
        self.revive();
    }

    fn try_move(&mut self, i: usize, to: Metres, crowd: &mut Crowd) -> MoveOutcome {
        if !(to.x.is_finite() && to.y.is_finite()) {
            return MoveOutcome::OutOfMap;
        }
        let from = self.bodies[i].pose;
        match crate::motion::validate_move_among(
            &self.truth.grid,
            &self.truth.info,
            from,
            to,
            self.max_step_m,
            &crowd.without(self.bodies[i].id),
            self.radius_m,
        ) {
            Ok(pose) => {
                self.bodies[i].distance_m += pose.xy().dist(from.xy());
                self.bodies[i].pose = pose;
                crowd.place(i, Some(pose.xy()));
                MoveOutcome::Moved
            }
            Err(outcome) => outcome,
        }
    }

    /// A dead robot (or base station) showed life again: it is alive from the next step on —
    /// where it stood when it died — and is sent scans again. Returns whether this made it
    /// rejoin (it was dead and not rejoining yet).
    pub fn rejoin(&mut self, id: RobotId) -> bool {
        let dead = self.bodies.get(usize::from(id)).is_some_and(|b| !b.alive)
            || self.base.as_ref().is_some_and(|b| b.id == id && !b.alive);
        dead && self.rejoining.insert(id)
    }

    /// A live robot's command came after its step ended: it is slow, not dead — its misses in a
    /// row start again (a robot that waited in vain for a frozen neighbour's step marker sends
    /// its command late; only the frozen one is declared dead).
    pub fn heard_late(&mut self, id: RobotId) {
        if let Some(b) = self.bodies.get_mut(usize::from(id)).filter(|b| b.alive) {
            b.missed = 0;
        }
    }

    /// Brings the rejoining nodes back to life (at the end of a step, before its status).
    fn revive(&mut self) {
        for id in std::mem::take(&mut self.rejoining) {
            if let Some(b) = self.bodies.get_mut(usize::from(id)) {
                b.alive = true;
                b.missed = 0;
                b.last_move = MoveOutcome::Stayed;
            }
            if let Some(b) = self.base.as_mut().filter(|b| b.id == id) {
                b.alive = true;
            }
        }
    }

    /// Marks a robot (or the base station) dead at once (its sim-plane session vanished).
    pub fn kill(&mut self, id: RobotId) {
        if let Some(b) = self.bodies.get_mut(usize::from(id)) {
            b.alive = false;
        }
        if let Some(b) = self.base.as_mut().filter(|b| b.id == id) {
            b.alive = false;
        }
    }

    /// Every node the world waits for in a step: the live robots, then the base station.
    pub fn awaited(&self) -> impl Iterator<Item = RobotId> + '_ {
        self.alive()
            .chain(self.base.iter().filter(|b| b.alive).map(|b| b.id))
    }

    /// Whether the world waits for node `id` in a step (it is alive).
    pub fn is_awaited(&self, id: RobotId) -> bool {
        self.awaited().any(|a| a == id)
    }

    /// Node ids: the robots, then the base station.
    pub fn nodes(&self) -> usize {
        self.bodies.len() + usize::from(self.base.is_some())
    }

    pub fn alive(&self) -> impl Iterator<Item = RobotId> + '_ {
        self.bodies.iter().filter(|b| b.alive).map(|b| b.id)
    }

    pub fn status(&self, step: Step) -> Status {
        Status {
            step,
            robots: self
                .bodies
                .iter()
                .map(|b| RobotStatus {
                    id: b.id,
                    pose: b.pose,
                    alive: b.alive,
                    distance_m: b.distance_m,
                })
                .collect(),
            collisions_total: self.collisions_total,
            blocked_total: self.blocked_total,
            base: self.base.as_ref().map(|b| RobotStatus {
                id: b.id,
                pose: b.pose,
                alive: b.alive,
                distance_m: 0.0,
            }),
            missed: Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn world() -> World {
        let mut s = Scenario::default();
        s.world.map = "office".into();
        s.world.width_m = 20.0;
        s.world.height_m = 15.0;
        s.robots.count = 2;
        s.clock.dead_after = 2;
        World::build(&s, None).expect("a generated world")
    }

    #[test]
    fn a_robot_declared_dead_rejoins_at_the_next_step_where_it_stood() {
        let mut w = world();
        let before = w.bodies[1].pose;
        let only_0 = HashMap::from([(
            0,
            Cmd {
                step: 0,
                robot: 0,
                waypoint: None,
            },
        )]);
        w.apply(0, &only_0);
        assert!(w.bodies[1].alive, "one miss");
        w.apply(1, &only_0);
        assert!(!w.bodies[1].alive, "dead after dead_after misses");
        assert_eq!(w.awaited().collect::<Vec<_>>(), vec![0]);
        assert!(!w.rejoin(0), "a live robot does not rejoin");
        assert!(w.rejoin(1));
        assert!(!w.rejoin(1), "once");
        assert!(!w.bodies[1].alive, "not within the step it showed life in");
        w.apply(2, &only_0);
        assert!(w.bodies[1].alive);
        assert_eq!(w.bodies[1].missed, 0);
        assert_eq!(w.bodies[1].pose, before);
        assert_eq!(w.awaited().collect::<Vec<_>>(), vec![0, 1]);
        // A late command keeps a robot from being declared dead; silence does not.
        w.apply(3, &HashMap::new());
        w.heard_late(1);
        w.apply(4, &HashMap::new());
        assert!(w.bodies[1].alive && w.bodies[1].missed == 1);
        assert!(!w.bodies[0].alive, "robot 0 missed steps 3 and 4 in a row");
        w.kill(1);
        assert!(!w.bodies[1].alive);
        assert!(w.rejoin(1));
        w.apply(5, &only_0);
        assert!(w.status(6).robots[1].alive);
    }
}
