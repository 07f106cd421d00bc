//! How long a lockstep step may take on the wall clock (docs/design.md §2.1): the one rule that
//! the world-server's wait for a step's commands and a robot's patience with a silent world
//! both follow, so that they fit the team and the machine without a flag.
//!
//! * Never less than `clock.step_timeout_ms`, the floor (a small team on an idle machine).
//! * Until a step has been seen whole, the start allowance: the floor once for every
//!   [`NODES_PER_FLOOR`](crate::step_wait::NODES_PER_FLOOR) nodes
//!   ([`start_ms`](crate::step_wait::start_ms)). The first steps open every radio session at once,
//!   and take the longer the more processes share the machine (128 robots on two cores: about 4 s
//!   for step 0).
//! * Then [`FACTOR`](crate::step_wait::FACTOR) times the longest of the last
//!   [`WINDOW`](crate::step_wait::WINDOW) whole steps: the wait follows the run as its steps grow
//!   slower (more robots, bigger maps, a loaded machine).
//!
//! A step is whole when nobody was waited out. A step cut short by a silent robot is not
//! measured, so a hung robot does not lengthen the wait for the next. In a deterministic run no
//! wait runs out, so the rule decides nothing there; it decides how soon a hung process is
//! found: a robot silent for `clock.dead_after` steps in a row is declared dead after at most
//! `dead_after` × [`StepWait::limit`](crate::step_wait::StepWait::limit) of wall time.
//!
//! **Invariant:** the limit is never below the floor, and never below
//! [`FACTOR`](crate::step_wait::FACTOR) times a whole step of the window (property test
//! `the_limit_covers_the_floor_and_every_recent_step`).

use std::collections::VecDeque;
use std::time::Duration;

/// The limit is this many times the longest recent whole step.
pub const FACTOR: u32 = 10;

/// How many whole steps the limit looks back on.
pub const WINDOW: usize = 32;

/// The start allowance is the floor once per this many nodes.
pub const NODES_PER_FLOOR: usize = 8;

/// The start allowance of a team of `nodes` (robots and base station): `floor_ms` once for
/// every [`NODES_PER_FLOOR`] of them, at least once.
pub fn start_ms(floor_ms: u64, nodes: usize) -> u64 {
    let units = u64::try_from(nodes.div_ceil(NODES_PER_FLOOR).max(1)).unwrap_or(u64::MAX);
    floor_ms.saturating_mul(units)
}

/// The wait for a step, as the steps seen so far make it.
#[derive(Clone, Debug)]
pub struct StepWait {
    floor: Duration,
    start: Duration,
    recent: VecDeque<Duration>,
}

impl StepWait {
    /// A wait of at least `floor`, `start` until a step is seen whole.
    pub fn new(floor: Duration, start: Duration) -> StepWait {
        StepWait {
            floor,
            start: start.max(floor),
            recent: VecDeque::with_capacity(WINDOW),
        }
    }

    /// How long the next step may take before whoever is still awaited is waited out.
    pub fn limit(&self) -> Duration {
        match self.recent.iter().max() {
            None => self.start,
            Some(&longest) => self.floor.max(longest.saturating_mul(FACTOR)),
        }
    }

    /// A step came in whole, in `took`.
    pub fn whole(&mut self, took: Duration) {
        if self.recent.len() == WINDOW {
            self.recent.pop_front();
        }
        self.recent.push_back(took);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn a_small_team_waits_the_floor_and_a_big_one_longer_until_a_step_is_whole() {
        assert_eq!(start_ms(2000, 4), 2000);
        assert_eq!(start_ms(2000, 8), 2000);
        assert_eq!(start_ms(2000, 9), 4000);
        assert_eq!(start_ms(2000, 128), 32_000);
        assert_eq!(start_ms(u64::MAX, 1000), u64::MAX);
        let mut w = StepWait::new(2000 * MS, 32_000 * MS);
        assert_eq!(w.limit(), 32_000 * MS);
        w.whole(900 * MS);
        assert_eq!(w.limit(), 9_000 * MS, "ten times the step");
        w.whole(50 * MS);
        assert_eq!(w.limit(), 9_000 * MS, "the longest of the window");
        for _ in 0..WINDOW {
            w.whole(5 * MS);
        }
        assert_eq!(
            w.limit(),
            2000 * MS,
            "the slow step left the window: the floor"
        );
    }

    proptest! {
        #[test]
        fn the_limit_covers_the_floor_and_every_recent_step(
            floor in 1u32..5_000,
            start in 0u32..100_000,
            steps in prop::collection::vec(0u32..20_000, 0..80),
        ) {
            let mut w = StepWait::new(floor * MS, start * MS);
            for &s in &steps {
                w.whole(s * MS);
            }
            let limit = w.limit();
            prop_assert!(limit >= floor * MS);
            let window = steps.iter().rev().take(WINDOW);
            for &s in window {
                prop_assert!(limit >= s * MS * FACTOR, "{limit:?} < {FACTOR} × {s} ms");
            }
            if steps.is_empty() {
                prop_assert_eq!(limit, (start.max(floor)) * MS);
            }
        }
    }
}
