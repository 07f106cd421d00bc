//! The incremental approximation A_t of a robot's self-explored grid (thesis §4.2.1, §5.1.1).
//!
//! [`Approximator`](crate::mapping::approximator::Approximator) derives A_t
//! ([`crate::mapping::approx`]) from A_{t−1} and P_t (§4.2.1): vertices no longer on P_t are
//! dropped (their neighbours connect); the rest are grouped by the P_t object they lie on, which
//! cuts objects that split; each group is closed along P_t by ordering it in P_t's cyclic order
//! (the same as tracing P_t from a chain end to the next vertex); a lone vertex gets the P_t point
//! farthest from it, an object without vertices its first point and the one farthest from that. The
//! group also joins objects that merged. Then [`crate::mapping::refine`] splits edges at the
//! splitting frequency s (§5.1.1): s accumulates, so s = 0.2 splits once every fifth step.
//!
//! Identity (docs/design.md §4.2): an old object and a P_t object are matched greedily by how many
//! vertices they share, most first; a matched object keeps its id (and its first vertex, so
//! unchanged objects give empty edit scripts), every other P_t object gets a fresh id.
//!
//! Place among the mapping modules: it builds on [`crate::mapping::approx`] (the model),
//! [`crate::mapping::refine`] (the splits) and [`crate::mapping::render`] (the exploration view the
//! monotone splits are scored against). Of the crate, only the mapping pipeline
//! ([`crate::exchange::mapper`]) uses it.

use std::collections::BTreeMap;

use proto::grid::Grid;

use crate::mapping::approx::{Approximation, ObjectId};
use crate::mapping::contour::{Contour, Contours};
use crate::mapping::refine::{refine, Draft, Refined};
use crate::mapping::render::exploration_view;

/// The incremental approximation of one robot's self-explored grid across steps.
#[derive(Clone, Debug)]
pub struct Approximator {
    current: Approximation,
    next_id: ObjectId,
    credit: f64,
    last: Refined,
    /// Monotone refinement (see [`crate::mapping::refine`]); `false` is the thesis's plain DP.
    pub monotone: bool,
}

impl Default for Approximator {
    fn default() -> Approximator {
        let last = Refined {
            splits: 0,
            waiting: false,
        };
        Approximator {
            current: Approximation::default(),
            next_id: 0,
            credit: 0.0,
            last,
            monotone: true,
        }
    }
}

impl Approximator {
    pub fn new() -> Approximator {
        Approximator::default()
    }

    /// A_{t−1}, the approximation of the last step.
    pub fn current(&self) -> &Approximation {
        &self.current
    }

    /// What the last step's refinement did (splits made; whether a group waits for credit).
    pub fn last_refinement(&self) -> Refined {
        self.last
    }

    /// One step: A_t from A_{t−1} and P_t = the contours of `own` (G_s), refined with the
    /// splits that `splits_per_step` (fractional, accumulating; infinite = until exact) makes
    /// due this step. Credit left over only while an atomic group of splits waits for room.
    pub fn step(&mut self, p: &Contours, own: &Grid, splits_per_step: f64) -> &Approximation {
        self.step_in_view(p, &exploration_view(own), splits_per_step)
    }

    /// [`Self::step`] given G_s's exploration view (kept:
    /// [`crate::mapping::render::ExplorationView`]).
    pub fn step_in_view(
        &mut self,
        p: &Contours,
        view: &Grid,
        splits_per_step: f64,
    ) -> &Approximation {
        let budget = if splits_per_step.is_finite() {
            self.credit += splits_per_step.max(0.0);
            self.credit.floor() as usize
        } else {
            usize::MAX
        };
        let mut drafts = derive(&self.current, p, &mut self.next_id);
        let view = self.monotone.then_some(view);
        let done = refine(&mut drafts, p, view, budget);
        self.last = done;
        self.credit = if done.waiting {
            self.credit - done.splits as f64
        } else {
            self.credit.fract()
        };
        self.current = finish(drafts);
        &self.current
    }
}

/// A_t from scratch for a fixed P_t (the contours of `own`) with `splits` monotone
/// Douglas–Peucker splits (fewer once exact): the approximation as a function of effort.
pub fn approximate(p: &Contours, own: &Grid, splits: usize) -> Approximation {
    let mut drafts = derive(&Approximation::default(), p, &mut 0);
    refine(&mut drafts, p, Some(&exploration_view(own)), splits);
    finish(drafts)
}

/// A vertex of A_{t−1} that still lies on P_t: point index there, old object, old position.
#[derive(Clone, Copy, Debug)]
struct Survivor {
    idx: usize,
    id: ObjectId,
    pos: usize,
}

/// Steps 1–3 of §4.2.1: a valid (unrefined) A_t, as drafts sorted by id.
fn derive(prev: &Approximation, p: &Contours, next_id: &mut ObjectId) -> Vec<Draft> {
    let mut on: Vec<Vec<Survivor>> = vec![Vec::new(); p.objects().len()];
    for (&id, poly) in &prev.objects {
        for (pos, v) in poly.vertices.iter().enumerate() {
            if let Some((o, idx)) = p.locate(v.p) {
                on[o].push(Survivor { idx, id, pos });
            }
        }
    }
    let ids = match_ids(&on, next_id);
    let mut drafts: Vec<Draft> = on
        .iter()
        .enumerate()
        .map(|(o, s)| close(&p.objects()[o], ids[o], o, s))
        .collect();
    drafts.sort_by_key(|d| d.id);
    drafts
}

/// The id of every P_t object: greedy one-to-one matching of old ids by shared vertices.
fn match_ids(on: &[Vec<Survivor>], next_id: &mut ObjectId) -> Vec<ObjectId> {
    let mut shared: BTreeMap<(ObjectId, usize), usize> = BTreeMap::new();
    for (o, survivors) in on.iter().enumerate() {
        for s in survivors {
            *shared.entry((s.id, o)).or_default() += 1;
        }
    }
    let mut pairs: Vec<((ObjectId, usize), usize)> = shared.into_iter().collect();
    pairs.sort_by_key(|&((id, o), count)| (std::cmp::Reverse(count), id, o));
    let mut ids: Vec<Option<ObjectId>> = vec![None; on.len()];
    let mut used = std::collections::BTreeSet::new();
    for ((id, o), _) in pairs {
        if ids[o].is_none() && used.insert(id) {
            ids[o] = Some(id);
        }
    }
    ids.into_iter()
        .map(|id| {
            id.unwrap_or_else(|| {
                *next_id += 1;
                *next_id - 1
            })
        })
        .collect()
}

/// Orders the survivors on one P_t object cyclically, starting where the object's old array
/// started, and tops it up to two vertices.
fn close(c: &Contour, id: ObjectId, pobj: usize, survivors: &[Survivor]) -> Draft {
    let mut idx: Vec<usize> = survivors.iter().map(|s| s.idx).collect();
    idx.sort_unstable();
    idx.dedup();
    let first = survivors
        .iter()
        .filter(|s| s.id == id)
        .min_by_key(|s| s.pos);
    if let Some(k) = first.and_then(|f| idx.iter().position(|&i| i == f.idx)) {
        idx.rotate_left(k);
    }
    match idx[..] {
        [] => idx = vec![0, farthest(c, 0)],
        [a] => idx.push(farthest(c, a)),
        _ => {}
    }
    Draft::new(id, pobj, idx, c)
}

/// The point of `c` farthest from point `from` (lowest index on ties).
fn farthest(c: &Contour, from: usize) -> usize {
    let a = c.points[from];
    (0..c.points.len())
        .max_by_key(|&i| (c.points[i].dist2(a), std::cmp::Reverse(i)))
        .unwrap_or(0)
}

/// Drafts → A_t.
fn finish(drafts: Vec<Draft>) -> Approximation {
    Approximation {
        objects: drafts.into_iter().map(|d| (d.id, d.poly)).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::approx::Vertex;
    use crate::mapping::approx_error::approx_error;
    use crate::mapping::contour::Kind;
    use crate::testutil::{arb_exploration, arb_grid, arb_grid_sequence, arb_map_window};
    use proptest::prelude::*;

    /// docs/design.md §4.2's validity: only P_t points, one object per P_t object with ≥ 2 vertices
    /// in P_t's cyclic order, kind and f_occ as P_t says.
    pub(crate) fn assert_valid(a: &Approximation, p: &Contours) {
        assert_eq!(
            a.objects.len(),
            p.objects().len(),
            "one object per object of P_t"
        );
        let mut seen = vec![false; p.objects().len()];
        for (id, poly) in &a.objects {
            let at: Vec<(usize, usize)> = poly
                .vertices
                .iter()
                .map(|v| p.locate(v.p).expect("vertex on P_t"))
                .collect();
            let o = at[0].0;
            assert!(
                at.iter().all(|&(oo, _)| oo == o),
                "object {id} spans objects of P_t"
            );
            assert!(
                !std::mem::replace(&mut seen[o], true),
                "two objects on P_t object {o}"
            );
            assert!(at.len() >= 2, "object {id} has {} vertices", at.len());
            let descents = (0..at.len())
                .filter(|&k| at[(k + 1) % at.len()].1 <= at[k].1)
                .count();
            assert_eq!(descents, 1, "object {id} out of P_t order");
            let c = &p.objects()[o];
            assert_eq!(poly.kind, c.kind);
            for k in 0..at.len() {
                assert_eq!(
                    poly.vertices[k].occ,
                    Vertex::spanning(c, at[k].1, at[(k + 1) % at.len()].1).occ
                );
            }
        }
    }

    /// Runs the approximator over ASCII steps with `s` splits per step; returns every A_t.
    fn check(steps: &[&str], s: f64) -> Vec<Approximation> {
        let mut ax = Approximator::new();
        steps
            .iter()
            .map(|pic| {
                let g = Grid::from_ascii(pic);
                let p = Contours::extract(&g);
                let a = ax.step(&p, &g, s).clone();
                assert_valid(&a, &p);
                a
            })
            .collect()
    }

    fn ids(a: &Approximation, kind: Kind) -> Vec<ObjectId> {
        a.objects
            .iter()
            .filter(|(_, o)| o.kind == kind)
            .map(|(&id, _)| id)
            .collect()
    }

    #[test]
    fn object_splitting_in_two_keeps_one_id() {
        let a = check(
            &[
                "........\n.######.\n........",
                "........\n.##.###.\n........",
            ],
            8.0,
        );
        let (before, after) = (ids(&a[0], Kind::Outside), ids(&a[1], Kind::Outside));
        assert_eq!(before.len(), 1);
        assert_eq!(after.len(), 2);
        assert!(after.contains(&before[0]), "the larger part keeps the id");
    }

    #[test]
    fn new_object_appears_with_two_vertices() {
        let a = check(&["......\n......\n......", "......\n...#..\n......"], 0.0);
        let new = ids(&a[1], Kind::Outside);
        assert_eq!(new.len(), 1);
        assert!(!a[0].objects.contains_key(&new[0]), "a fresh id");
        assert_eq!(a[1].objects[&new[0]].vertices.len(), 2);
    }

    #[test]
    fn vanished_object_is_gone() {
        let a = check(&["......\n..##..\n......", "......\n......\n......"], 1.0);
        assert_eq!(ids(&a[0], Kind::Outside).len(), 1);
        assert!(ids(&a[1], Kind::Outside).is_empty());
        assert_eq!(
            ids(&a[0], Kind::Inside),
            ids(&a[1], Kind::Inside),
            "the inside object stays"
        );
    }

    #[test]
    fn merging_objects_become_one() {
        let a = check(
            &[
                "#######\n#.....#\n#.#...#\n#.....#\n#######",
                "#######\n#.....#\n###...#\n#.....#\n#######",
            ],
            9.0,
        );
        assert_eq!(ids(&a[0], Kind::Outside).len(), 1);
        assert!(
            ids(&a[1], Kind::Outside).is_empty(),
            "the island joined the wall"
        );
        assert_eq!(ids(&a[0], Kind::Inside), ids(&a[1], Kind::Inside));
    }

    #[test]
    fn unchanged_grid_keeps_the_same_vertices_without_splits() {
        let pic = "?????\n.#...\n.....";
        let a = check(&[pic, pic, pic], 0.0);
        assert_eq!(a[0], a[2]);
    }

    #[test]
    fn fractional_splitting_frequency_accumulates() {
        let pic = "........\n.######.\n.#......\n........";
        let a = check(&[pic; 10], 0.2);
        let counts: Vec<usize> = a.iter().map(Approximation::vertex_count).collect();
        let grew = counts.windows(2).filter(|w| w[1] > w[0]).count();
        assert_eq!(grew, 2, "two splits in ten steps: {counts:?}");
    }

    /// d_t for 0..=max splits on one P_t.
    fn errors(g: &Grid, max: usize) -> Vec<usize> {
        let p = Contours::extract(g);
        (0..=max)
            .map(|k| approx_error(g, &approximate(&p, g, k)))
            .collect()
    }

    #[test]
    fn refinement_is_monotone_on_a_fixed_grid() {
        let g = Grid::from_ascii("??????????\n?....#...?\n?.##.#.#.?\n?.#..?...?\n?........?");
        let d = errors(&g, 40);
        assert!(d.windows(2).all(|w| w[1] <= w[0]), "{d:?}");
        assert_eq!(d.last(), Some(&0));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(96))]

        #[test]
        fn every_step_is_valid(seq in arb_exploration(20, 8), s in 0.0f64..6.0) {
            let mut ax = Approximator::new();
            for g in &seq {
                let p = Contours::extract(g);
                assert_valid(ax.step(&p, g, s), &p);
            }
        }

        #[test]
        fn every_step_is_valid_under_arbitrary_change(seq in arb_grid_sequence(10, 5), s in 0.0f64..4.0) {
            let mut ax = Approximator::new();
            for g in &seq {
                let p = Contours::extract(g);
                assert_valid(ax.step(&p, g, s), &p);
            }
        }

        #[test]
        fn unlimited_splits_reach_zero_error(g in arb_grid(14)) {
            let p = Contours::extract(&g);
            let a = approximate(&p, &g, usize::MAX);
            assert_valid(&a, &p);
            prop_assert_eq!(approx_error(&g, &a), 0);
        }

        #[test]
        fn more_splits_never_increase_the_error(g in arb_grid(12)) {
            let d = errors(&g, 60);
            prop_assert!(d.windows(2).all(|w| w[1] <= w[0]), "{:?}", d);
        }

        #[test]
        fn refinement_on_real_maps_is_monotone_and_reaches_zero(g in arb_map_window(28, 28)) {
            let d = errors(&g, 50);
            prop_assert!(d.windows(2).all(|w| w[1] <= w[0]), "{:?}", d);
            let p = Contours::extract(&g);
            prop_assert_eq!(approx_error(&g, &approximate(&p, &g, usize::MAX)), 0);
        }
    }
}
