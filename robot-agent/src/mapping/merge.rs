//! The planning grid G_p: merging other robots' approximations with the self-explored grid
//! G_s (thesis §5.2, Algorithm 9; docs/design.md §4.5).
//!
//! Principles: self-explored data wins; unknown space inside some robot's outside object stays
//! unknown only if no robot whose inside object covers it knows better; occupied and free
//! boundaries are never overwritten by unknown. Steps, over all approximations each:
//! (1) every cell `undefined`; (2) fill outside objects with unknown; (3) draw outside-object
//! edges, occupied → occupied, unknown → unknown (never over occupied); (4) per approximation,
//! cells inside one of its inside objects that are undefined, or unknown but free by that same
//! approximation, become free; (5) draw occupied edges of all objects (the thesis's Fig. 5.6(e)
//! "contours of all inside objects" — walls of the inside object appear only here);
//! (6) undefined → unknown; (7) every known cell of G_s overwrites.
//!
//! Interpretations. "Free by the same approximation" in (4) means inside an odd number of its
//! polygons (inside, hole, island in a hole, …): the thesis's "not in one of its outside
//! objects", extended so that a free region nested inside an outside object (a closed room
//! seen from outside and inside) is freed too. Free edges of inside objects are *not* drawn in
//! (5): they span contour pixels, which are never free, and drawing them free would invent a
//! free ring beyond every frontier; left undefined they read unknown, so the merge of an
//! unsimplified approximation reproduces G_s on every free cell and every cell 4-adjacent to
//! one (docs/design.md §4.1's exploration equivalence).
//!
//! Steps (1)–(5) paint polygons onto cells and are shared with the rendering of a single
//! approximation, so they live in [`crate::mapping::render`]; this module is Algorithm 9 itself: paint the
//! other robots' approximations, then let G_s win.

use proto::grid::{Grid, Occ, Rect};
use proto::msg::RobotId;

use crate::mapping::approx::Approximation;
use crate::mapping::painting::Painting;
use crate::mapping::render::Bands;

/// Algorithm 9: the planning grid from `own` (G_s) and other robots' approximations, all in
/// the frame of `own`.
pub fn merge(own: &Grid, others: &[&Approximation]) -> Grid {
    let mut out = Grid::new(own.width(), own.height(), Occ::Unknown);
    merge_into(&mut out, own, others);
    out
}

/// [`merge`] written over `out` (the last step's planning grid, of the same size), in
/// proportion to the explored part of the map: only the cells that G_s knows, that some
/// approximation paints, or that `out` knew are written — every other cell is and stays
/// unknown. A [`Merger`] that starts afresh.
pub fn merge_into(out: &mut Grid, own: &Grid, others: &[&Approximation]) {
    let others: Vec<(RobotId, &Approximation)> = (others.iter().enumerate())
        .map(|(i, a)| (RobotId::try_from(i).unwrap_or(RobotId::MAX), *a))
        .collect();
    Merger::default().merge_into(out, own, None, &others);
}

/// Algorithm 9 kept from step to step: [`merge_into`] with the peers' painting (steps (1)–(5))
/// kept over the whole grid and repainted only in the windows where an object changed
/// ([`Painting`]), and the planning grid rewritten only there and where G_s changed — so a
/// step costs what changed in the peers' approximations and in G_s, not all of them (a robot
/// holds every teammate's approximation it ever heard of) nor the explored part of the map.
#[derive(Default)]
pub struct Merger {
    painting: Option<Painting>,
}

impl Merger {
    /// [`merge_into`] `out` from `own` and the approximations of `others` (owner,
    /// approximation), repainting what changed since the last call. `out` is the planning
    /// grid this merger wrote last (untouched since), and every cell of `own` outside
    /// `own_changed` is as it was then (`None`: every cell); the first call, and one with a
    /// grid of another size, writes every cell `merge_into` does. Returns the rectangles
    /// written (inside the grid): every other cell of `out` is as it was.
    pub fn merge_into(
        &mut self,
        out: &mut Grid,
        own: &Grid,
        own_changed: Option<Rect>,
        others: &[(RobotId, &Approximation)],
    ) -> Vec<Rect> {
        let size = (own.width(), own.height());
        let kept = self.painting.take().filter(|p| p.size() == size);
        let fresh = kept.is_none();
        let painting = (self.painting)
            .insert(kept.unwrap_or_else(|| Painting::new(size.0, size.1, Bands::Kept)));
        let mut windows = painting.take(others);
        painting.repaint();
        if fresh {
            // The cells painted, those G_s knows and those `out` knew: every other cell is and
            // stays unknown.
            let region = [own.known_bounds(), out.known_bounds()]
                .into_iter()
                .fold(painting.reach(), Rect::union_of);
            windows = region.into_iter().collect();
        } else {
            windows.extend(own_changed);
        }
        let written: Vec<Rect> = (windows.into_iter())
            .filter_map(|r| r.within(size.0, size.1))
            .collect();
        for &r in &written {
            write(out, own, painting.painted(), r);
        }
        written
    }
}

/// Steps (6) and (7) over the cells of `r` (inside the grid): `out` from `own` and the peers'
/// painting (row-major over the whole grid).
fn write(out: &mut Grid, own: &Grid, painted: &[Option<Occ>], r: Rect) {
    let w = own.width() as usize;
    for y in r.min.y..=r.max.y {
        let row = y as usize * w;
        let painted = &painted[row + r.min.x as usize..=row + r.max.x as usize];
        let mine = own.row(y, r.min.x, r.max.x);
        let dst = out.row_mut(y, r.min.x, r.max.x);
        for ((dst, &s), &p) in dst.iter_mut().zip(mine).zip(painted) {
            *dst = planned(s, p);
        }
    }
}

/// (7) every known cell of G_s overwrites; (6) undefined reads unknown.
fn planned(own: Occ, painted: Option<Occ>) -> Occ {
    match (own, painted) {
        (Occ::Free | Occ::Occupied, _) => own,
        (_, Some(v)) => v,
        (_, None) => Occ::Unknown,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::approx::Polygon;
    use crate::mapping::contour::{Contours, Kind};
    use crate::mapping::render::exploration_view;
    use crate::mapping::render::paint;
    use crate::testutil::arb_grid;
    use proptest::prelude::*;
    use proto::grid::Cell;

    fn exact(g: &Grid) -> Approximation {
        Approximation::exact(&Contours::extract(g))
    }

    #[test]
    fn unknown_edges_never_overwrite_occupied_cells() {
        let own = Grid::new(5, 3, Occ::Unknown);
        let walls = exact(&Grid::from_ascii("?????\n.###.\n....."));
        let island = exact(&Grid::from_ascii(".....\n.???.\n....."));
        for order in [[&walls, &island], [&island, &walls]] {
            let g = merge(&own, &order);
            assert_eq!(g.to_ascii(), ".....\n.###.\n.....\n");
        }
    }

    /// Truth in the spirit of thesis Fig. 5.4(a): a star, a circle, a triangle, a rectangle.
    const WORLD: &str = "
        ################################
        #..............................#
        #...#........##................#
        #..###......####...............#
        #...#.......####...............#
        #............##................#
        #..............................#
        #..............................#
        #.......#..........#######.....#
        #......###.........#######.....#
        #.....#####........#######.....#
        #....#######...................#
        #..............................#
        ################################";

    /// The truth where `known(col, row-from-top)`, unknown elsewhere.
    fn view(truth: &Grid, known: impl Fn(i32, i32) -> bool) -> Grid {
        let mut g = Grid::new(truth.width(), truth.height(), Occ::Unknown);
        let top = truth.height() as i32 - 1;
        for y in 0..=top {
            for x in 0..truth.width() as i32 {
                if known(x, top - y) {
                    g.set(Cell::new(x, y), truth.get(Cell::new(x, y)));
                }
            }
        }
        g
    }

    #[test]
    fn three_robots_merge_like_figs_5_4_to_5_6() {
        let truth = Grid::from_ascii(WORLD);
        // Robot 1: the left part, but an unknown patch beside the star (it joins the star).
        let r1 = view(&truth, |x, r| {
            x <= 17 && !((6..=7).contains(&x) && (2..=4).contains(&r))
        });
        // Robot 2: the top part, with an unknown patch beside the circle.
        let r2 = view(&truth, |x, r| {
            r <= 6 && !((16..=17).contains(&x) && (3..=4).contains(&r))
        });
        // Robot 3 (merging): the bottom right with the rectangle.
        let own = view(&truth, |x, r| x >= 14 && r >= 7);
        let (a1, a2) = (exact(&r1), exact(&r2));
        let plan = merge(&own, &[&a1, &a2]);

        let views = [exploration_view(&r1), exploration_view(&r2)];
        let mut want = own.clone();
        for (i, w) in want.cells_mut().iter_mut().enumerate() {
            let said = |v: Occ| views.iter().any(|g| g.cells()[i] == v);
            if *w == Occ::Unknown {
                *w = if said(Occ::Free) {
                    Occ::Free
                } else if said(Occ::Occupied) {
                    Occ::Occupied
                } else {
                    Occ::Unknown
                };
            }
        }
        assert_eq!(plan.to_ascii(), want.to_ascii());
        // Each robot's unknown patch is free because the other robot saw it free.
        let top = truth.height() as i32 - 1;
        for (x, r) in [(6, 3), (7, 2), (16, 3), (17, 4)] {
            assert_eq!(
                plan.get(Cell::new(x, top - r)),
                Occ::Free,
                "patch cell {x},{r}"
            );
        }
    }

    /// [`merge`] as it was written before it knew the explored part: every cell painted.
    fn merge_every_cell(own: &Grid, others: &[&Approximation]) -> Grid {
        let polys: Vec<Vec<&Polygon>> = others
            .iter()
            .map(|a| a.objects.values().collect())
            .collect();
        let plan = paint(
            &polys,
            Cell::new(0, 0),
            own.width(),
            own.height(),
            Bands::Kept,
        );
        let mut out = Grid::new(own.width(), own.height(), Occ::Unknown);
        for (i, p) in plan.into_iter().enumerate() {
            let s = own.cells()[i];
            out.set_index(
                i,
                match (s, p) {
                    (Occ::Free | Occ::Occupied, _) => s,
                    (_, Some(v)) => v,
                    (_, None) => Occ::Unknown,
                },
            );
        }
        out
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(128))]

        /// Written over the last step's planning grid, only where something is known, the
        /// merge is the merge of every cell.
        #[test]
        fn the_kept_planning_grid_equals_the_merge_of_every_cell(
            (before, after) in (12u32..40, 12u32..40).prop_flat_map(|(w, h)| {
                let g = move || (crate::testutil::arb_grid(12), 0i32..40, 0i32..40)
                    .prop_map(move |(g, x, y)| crate::testutil::placed(&g, w, h, Cell::new(x % w as i32, y % h as i32)));
                ((g(), g()), (g(), g(), g()))
            })
        ) {
            let ((own0, peer0), (own1, peer1, peer2)) = (before, after);
            let mut kept = merge(&own0, &[&exact(&peer0)]);
            let (a, b) = (exact(&peer1), exact(&peer2));
            merge_into(&mut kept, &own1, &[&a, &b]);
            prop_assert_eq!(kept.to_ascii(), merge_every_cell(&own1, &[&a, &b]).to_ascii());
        }

        /// Kept from step to step over peers whose approximations grow, change in places,
        /// come and go, the merger's planning grid is the merge of every cell at every step.
        #[test]
        fn the_merger_s_planning_grid_is_the_merge_of_every_cell_at_every_step(
            peers in proptest::collection::vec(crate::testutil::arb_exploration(20, 5), 1..4),
            own in crate::testutil::arb_exploration(20, 5),
            s in prop_oneof![Just(0.0), Just(1.0), Just(4.0)],
            gone in proptest::collection::vec(any::<bool>(), 5),
        ) {
            let size = |g: &[Grid]| g.last().map(|g| (g.width(), g.height()));
            prop_assume!(peers.iter().all(|p| size(p) == size(&own)));
            let mut axs: Vec<_> = peers.iter().map(|_| crate::mapping::approximator::Approximator::new()).collect();
            let mut merger = Merger::default();
            let mut kept = Grid::new(own[0].width(), own[0].height(), Occ::Unknown);
            let mut own_was = Grid::new(own[0].width(), own[0].height(), Occ::Unknown);
            for step in 0..5 {
                let own = &own[step.min(own.len() - 1)];
                let differ = |a: &Grid, b: &Grid| -> Vec<proto::grid::Cell> {
                    (0..a.len()).filter(|&i| a.cells()[i] != b.cells()[i]).map(|i| a.cell_of(i)).collect()
                };
                let own_changed = Rect::around(differ(&own_was, own));
                own_was = own.clone();
                let kept_was = kept.clone();
                let approx: Vec<Approximation> = (peers.iter().zip(&mut axs))
                    .map(|(p, ax)| {
                        let g = &p[step.min(p.len() - 1)];
                        ax.step(&Contours::extract(g), g, s).clone()
                    })
                    .collect();
                // A peer is left out now and then (a restart dropped its replica).
                let others: Vec<(RobotId, &Approximation)> = (approx.iter().enumerate())
                    .filter(|(i, _)| !(gone[step] && *i == step % approx.len()))
                    .map(|(i, a)| (i as RobotId, a))
                    .collect();
                let written = merger.merge_into(&mut kept, own, own_changed, &others);
                let all: Vec<&Approximation> = others.iter().map(|o| o.1).collect();
                prop_assert_eq!(kept.to_ascii(), merge_every_cell(own, &all).to_ascii(), "step {}", step);
                for c in differ(&kept_was, &kept) {
                    prop_assert!(written.iter().any(|r| r.contains(c)), "{:?} changed outside {:?}", c, written);
                }
            }
        }

        /// A peer's approximation, at any splitting frequency, never makes a receiver believe
        /// free a cell the peer did not see free: what a coarse edge may claim lies within its
        /// error bound, which the receiver keeps from being painted free.
        #[test]
        fn a_received_approximation_paints_free_only_what_its_owner_saw_free(
            steps in crate::testutil::arb_exploration(16, 4),
            s in prop_oneof![Just(0.0), Just(0.5), Just(2.0), Just(8.0)],
        ) {
            let mut ax = crate::mapping::approximator::Approximator::new();
            let mut a = Approximation::default();
            for g in &steps {
                a = ax.step(&Contours::extract(g), g, s).clone();
            }
            let seen = steps.last().expect("a step");
            let plan = merge(&Grid::new(seen.width(), seen.height(), Occ::Unknown), &[&a]);
            for (i, (p, s)) in plan.cells().iter().zip(seen.cells()).enumerate() {
                prop_assert!(*p != Occ::Free || *s == Occ::Free, "cell {} painted free:\n{}\nseen:\n{}", i, plan.to_ascii(), seen.to_ascii());
            }
        }

        #[test]
        fn merging_arbitrary_polygons_never_panics(
            polys in proptest::collection::vec((any::<bool>(), proptest::collection::vec((any::<i32>(), any::<i32>(), 0u8..3, any::<u16>()), 0..6)), 0..4)
        ) {
            let mut a = Approximation::default();
            for (id, (inside, vs)) in polys.into_iter().enumerate() {
                let kind = if inside { Kind::Inside } else { Kind::Outside };
                let occ = |o: u8| [Occ::Free, Occ::Occupied, Occ::Unknown][usize::from(o)];
                let vertices = vs.into_iter().map(|(x, y, o, bound)| crate::mapping::approx::Vertex { p: crate::mapping::qpoint::QPoint::new(x, y), occ: occ(o), bound }).collect();
                a.objects.insert(id as u32, Polygon { kind, vertices });
            }
            let g = merge(&Grid::new(8, 8, Occ::Unknown), &[&a]);
            prop_assert_eq!(g.len(), 64);
        }

        #[test]
        fn merge_never_overwrites_known_cells(
            (own, a, b) in (4u32..14, 4u32..14).prop_flat_map(|(w, h)| {
                let g = move || arb_grid(14).prop_map(move |g| crate::testutil::window(&g, w, h, 0, 0));
                (g(), g(), g())
            })
        ) {
            let (a, b) = (exact(&a), exact(&b));
            let plan = merge(&own, &[&a, &b]);
            for (p, s) in plan.cells().iter().zip(own.cells()) {
                prop_assert!(*s == Occ::Unknown || p == s);
            }
        }
    }
}
