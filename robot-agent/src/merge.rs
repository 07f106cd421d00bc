//! The planning grid G_p: merging other robots' approximations with the self-explored grid
//! G_s (thesis §5.2, Algorithm 9; DESIGN §4.5).
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
//! one (DESIGN §4.1's exploration equivalence).

use proto::grid::{Cell, Grid, Occ};

use crate::approx::{Approximation, Polygon};
use crate::contour::Kind;
use crate::raster;

/// Cell states while merging: the grid's three plus `Undefined` (no approximation said).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Plan {
    Undefined,
    Known(Occ),
}

/// A working canvas over the window `[x0, x0+width) × [y0, y0+height)` of the grid frame.
struct Canvas {
    x0: i32,
    y0: i32,
    width: u32,
    height: u32,
    cells: Vec<Plan>,
}

impl Canvas {
    fn new(origin: Cell, width: u32, height: u32) -> Canvas {
        let cells = vec![Plan::Undefined; width as usize * height as usize];
        Canvas {
            x0: origin.x,
            y0: origin.y,
            width,
            height,
            cells,
        }
    }

    fn index(&self, c: Cell) -> Option<usize> {
        let (x, y) = (c.x - self.x0, c.y - self.y0);
        let inside = x >= 0 && y >= 0 && (x as u32) < self.width && (y as u32) < self.height;
        inside.then(|| y as usize * self.width as usize + x as usize)
    }

    /// Every cell of the window whose centre lies inside `poly`, by index.
    fn fill(&self, poly: &Polygon, mut f: impl FnMut(usize)) {
        let (x_end, w) = (self.x0 + self.width as i32 - 1, self.width as usize);
        let rows = self.y0..self.y0 + self.height as i32;
        raster::fill(&poly.points(), rows, |y, xa, xb| {
            let row = (y - self.y0) as usize * w;
            for x in xa.max(self.x0)..=xb.min(x_end) {
                f(row + (x - self.x0) as usize);
            }
        });
    }

    /// Every cell of the window on an edge of `poly`, with the edge's occupancy.
    fn edges(&mut self, poly: &Polygon, mut f: impl FnMut(&mut Plan, Occ)) {
        let n = poly.vertices.len();
        let lo = Cell::new(self.x0, self.y0);
        let hi = Cell::new(
            self.x0 + self.width as i32 - 1,
            self.y0 + self.height as i32 - 1,
        );
        for (i, v) in poly.vertices.iter().enumerate() {
            let next = poly.vertices[(i + 1) % n].p;
            raster::edge(v.p, next, lo, hi, |c| {
                if let Some(k) = self.index(c) {
                    f(&mut self.cells[k], v.occ);
                }
            });
        }
    }
}

/// Algorithm 9: the planning grid from `own` (G_s) and other robots' approximations, all in
/// the frame of `own`.
pub fn merge(own: &Grid, others: &[&Approximation]) -> Grid {
    let polys: Vec<Vec<&Polygon>> = others
        .iter()
        .map(|a| a.objects.values().collect())
        .collect();
    let plan = merged(
        Canvas::new(Cell::new(0, 0), own.width(), own.height()),
        &polys,
    );
    let mut out = Grid::new(own.width(), own.height(), Occ::Unknown);
    for ((dst, &p), &s) in out.cells_mut().iter_mut().zip(&plan.cells).zip(own.cells()) {
        *dst = match (s, p) {
            (Occ::Free | Occ::Occupied, _) => s,
            (_, Plan::Known(v)) => v,
            (_, Plan::Undefined) => Occ::Unknown,
        };
    }
    out
}

/// Steps (1)–(5) on a canvas; each approximation as the list of its polygons.
fn merged(mut plan: Canvas, others: &[Vec<&Polygon>]) -> Canvas {
    let outside = || others.iter().flatten().filter(|o| o.kind == Kind::Outside);
    for o in outside() {
        let mut unknown = Vec::new();
        plan.fill(o, |k| unknown.push(k));
        unknown
            .into_iter()
            .for_each(|k| plan.cells[k] = Plan::Known(Occ::Unknown));
    }
    for o in outside() {
        plan.edges(o, |cell, occ| match occ {
            Occ::Occupied => *cell = Plan::Known(Occ::Occupied),
            Occ::Unknown if *cell != Plan::Known(Occ::Occupied) => {
                *cell = Plan::Known(Occ::Unknown)
            }
            _ => {}
        });
    }
    for a in others {
        free_inside(&mut plan, a);
    }
    for o in others.iter().flatten() {
        plan.edges(o, |cell, occ| {
            if occ == Occ::Occupied {
                *cell = Plan::Known(Occ::Occupied);
            }
        });
    }
    plan
}

/// Step (4) for one approximation: cells inside its inside objects that are undefined, or
/// unknown but inside an odd number of its polygons, become free.
fn free_inside(plan: &mut Canvas, a: &[&Polygon]) {
    const INSIDE: u8 = 1;
    const ODD: u8 = 2;
    let mut flags = vec![0u8; plan.cells.len()];
    for o in a {
        let bit = if o.kind == Kind::Inside { INSIDE } else { 0 };
        plan.fill(o, |k| flags[k] = (flags[k] | bit) ^ ODD);
    }
    for (cell, f) in plan.cells.iter_mut().zip(flags) {
        let free = match *cell {
            Plan::Undefined => f & INSIDE != 0,
            Plan::Known(Occ::Unknown) => f & INSIDE != 0 && f & ODD != 0,
            Plan::Known(_) => false,
        };
        if free {
            *cell = Plan::Known(Occ::Free);
        }
    }
}

/// [`render`] of the approximation made of `polys`, restricted to the window of
/// `width × height` cells at `origin`, row-major: inside the grid identical to the same cells of the full
/// rendering, at the cost of the window (and one pass over the edges) — used to score a
/// single split locally.
pub fn render_window(polys: &[&Polygon], origin: Cell, width: u32, height: u32) -> Vec<Occ> {
    let plan = merged(Canvas::new(origin, width, height), &[polys.to_vec()]);
    plan.cells
        .iter()
        .map(|p| {
            if let Plan::Known(v) = *p {
                v
            } else {
                Occ::Unknown
            }
        })
        .collect()
}

/// The grid an approximation stands for on its own (`width × height`, the owner's frame):
/// Algorithm 9 with an empty G_s.
pub fn render(a: &Approximation, width: u32, height: u32) -> Grid {
    merge(&Grid::new(width, height, Occ::Unknown), &[a])
}

/// G_s as any polygonal model can represent it: non-free cells with no free 4-neighbour
/// (buried behind other non-free cells) read unknown. [`render`] of the unsimplified
/// approximation equals exactly this (exploration equivalence, DESIGN §4.1).
pub fn exploration_view(g: &Grid) -> Grid {
    let (w, h) = (g.width() as usize, g.height() as usize);
    let cells = g.cells();
    let free = |i: usize| cells[i] == Occ::Free;
    let mut out = g.clone();
    for (i, dst) in out.cells_mut().iter_mut().enumerate() {
        let (x, y) = (i % w, i / w);
        let exposed = (x > 0 && free(i - 1))
            || (x + 1 < w && free(i + 1))
            || (y > 0 && free(i - w))
            || (y + 1 < h && free(i + w));
        if !free(i) && !exposed {
            *dst = Occ::Unknown;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contour::Contours;
    use crate::testutil::{arb_grid, arb_map_window};
    use proptest::prelude::*;

    fn exact(g: &Grid) -> Approximation {
        Approximation::exact(&Contours::extract(g))
    }

    /// Rendering the unsimplified approximation of `pic` gives back `pic` (buried cells read
    /// unknown).
    fn check(pic: &str) {
        let g = Grid::from_ascii(pic);
        let got = render(&exact(&g), g.width(), g.height());
        assert_eq!(
            got.to_ascii(),
            exploration_view(&g).to_ascii(),
            "render of\n{pic}"
        );
    }

    #[test]
    fn exact_renders_reproduce_the_grid() {
        check("...\n.#.\n...");
        check("?##\n...");
        check("....\n.#..\n..#.\n....");
        check("####\n#.##\n##.#\n####");
        check(".......\n.#####.\n.#...#.\n.#####.\n.......");
        check(".......\n.##?##.\n.#?.?#.\n.#####.\n.......");
        check("#####\n#???#\n#?#?#\n#...#\n#####");
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

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(128))]

        #[test]
        fn exploration_equivalence_on_random_grids(g in arb_grid(16)) {
            let got = render(&exact(&g), g.width(), g.height());
            prop_assert_eq!(got.to_ascii(), exploration_view(&g).to_ascii());
        }

        #[test]
        fn exploration_equivalence_on_real_maps(g in arb_map_window(48, 48)) {
            let got = render(&exact(&g), g.width(), g.height());
            prop_assert_eq!(got.to_ascii(), exploration_view(&g).to_ascii());
        }

        #[test]
        fn window_renders_agree_with_full_renders(
            g in arb_grid(14), splits in 0usize..12, (x, y, w, h) in (0i32..14, 0i32..14, 1u32..8, 1u32..8)
        ) {
            let a = crate::approx::approximate(&Contours::extract(&g), &g, splits);
            let full = render(&a, g.width(), g.height());
            let polys: Vec<&Polygon> = a.objects.values().collect();
            let win = render_window(&polys, Cell::new(x, y), w, h);
            for (k, got) in win.iter().enumerate() {
                let c = Cell::new(x + (k as u32 % w) as i32, y + (k as u32 / w) as i32);
                // A simplified outside polygon may reach past the grid; `render` clips there
                // and so does every caller of `render_window` (refine's windows).
                if !g.contains(c) {
                    continue;
                }
                prop_assert_eq!(*got, full.get(c), "cell {:?}", c);
            }
        }

        #[test]
        fn merging_arbitrary_polygons_never_panics(
            polys in proptest::collection::vec((any::<bool>(), proptest::collection::vec((any::<i32>(), any::<i32>(), 0u8..3), 0..6)), 0..4)
        ) {
            let mut a = Approximation::default();
            for (id, (inside, vs)) in polys.into_iter().enumerate() {
                let kind = if inside { Kind::Inside } else { Kind::Outside };
                let occ = |o: u8| [Occ::Free, Occ::Occupied, Occ::Unknown][usize::from(o)];
                let vertices = vs.into_iter().map(|(x, y, o)| crate::approx::Vertex { p: crate::qpoint::QPoint::new(x, y), occ: occ(o) }).collect();
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
