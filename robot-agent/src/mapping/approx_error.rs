//! The approximation error of thesis §6.1: d_t, the number of cells in which the
//! self-explored grid G_s and the grid rendered from the approximation A_t differ, and its
//! average e_avg = Σ_{t=1}^{n} d_t / (g · n) (eq. 6.1) over n steps and g explored cells.
//!
//! Interpretation: G_s is compared in its
//! [`exploration_view`](crate::mapping::render::exploration_view) — non-free cells with no free
//! 4-neighbour read unknown — because no contour model carries cells buried behind other non-free
//! cells (the thesis's own rendering fills them with unknown as well). So d_t is 0 for the
//! unsimplified approximation and counts exactly what simplification loses or invents. Both grids
//! must share one frame.

use proto::grid::{Grid, Occ, Rect};

use crate::mapping::approx::{Approximation, Polygon};
use crate::mapping::painting::Painting;
use crate::mapping::render::{exploration_view, render_window, Bands};

/// d_t: cells where `own` (G_s, in its exploration view) and the rendering of `a` differ.
pub fn approx_error(own: &Grid, a: &Approximation) -> usize {
    approx_error_in_view(&exploration_view(own), a)
}

/// [`approx_error`] given G_s's exploration view (kept:
/// [`crate::mapping::render::ExplorationView`]). Compares only where either says something: the
/// known part of the view and the cells the approximation paints.
pub fn approx_error_in_view(view: &Grid, a: &Approximation) -> usize {
    let Some(r) = Rect::union_of(view.known_bounds(), a.cell_bounds())
        .and_then(|r| r.within(view.width(), view.height()))
    else {
        return 0;
    };
    let polys: Vec<&Polygon> = a.objects.values().collect();
    let rendered = render_window(&polys, r.min, r.width(), r.height());
    (r.min.y..=r.max.y)
        .zip(rendered.chunks(r.width() as usize))
        .map(|(y, painted)| {
            let seen = view.row(y, r.min.x, r.max.x);
            seen.iter().zip(painted).filter(|(v, p)| v != p).count()
        })
        .sum()
}

/// d_t kept from step to step: the rendering of the owner's approximation kept over the grid
/// and repainted where its objects changed ([`Painting`], bands ignored), and the cells where it
/// and G_s's exploration view differ counted where either changed — so a step late in a big
/// map costs what changed, not the explored part. [`approx_error_in_view`] is what it counts.
#[derive(Clone, Debug)]
pub struct KeptError {
    painting: Painting,
    /// Cells where the view and the rendering differ.
    differ: usize,
}

impl KeptError {
    /// Nothing rendered yet, over a grid whose exploration view is `view`.
    pub fn new(view: &Grid) -> KeptError {
        KeptError {
            painting: Painting::new(view.width(), view.height(), Bands::Ignored),
            differ: view.len() - view.count(Occ::Unknown),
        }
    }

    /// The view is about to change within `r`: its cells there leave the count.
    pub fn before_view(&mut self, view: &Grid, r: Rect) {
        self.differ -= self.differ_in(view, r);
    }

    /// The view changed within `r` (after [`KeptError::before_view`]): its cells there come back.
    pub fn after_view(&mut self, view: &Grid, r: Rect) {
        self.differ += self.differ_in(view, r);
    }

    /// d_t of `a` against `view`: the rendering repainted where `a` changed since the last call.
    pub fn error(&mut self, view: &Grid, a: &Approximation) -> usize {
        // The rendering ignores the edges' error bounds: held without them, an edge whose
        // bound alone changed is no change, and no window grows by a band.
        let mut a = a.clone();
        a.drop_bounds();
        let windows = self.painting.take(&[(0, &a)]);
        for &w in &windows {
            self.differ -= self.differ_in(view, w);
        }
        self.painting.repaint();
        for &w in &windows {
            self.differ += self.differ_in(view, w);
        }
        self.differ
    }

    /// The cells of `r` where `view` and the rendering differ (undefined reads unknown).
    fn differ_in(&self, view: &Grid, r: Rect) -> usize {
        let (w, h) = self.painting.size();
        let Some(r) = r.within(w, h) else {
            return 0;
        };
        let painted = self.painting.painted();
        (r.min.y..=r.max.y)
            .map(|y| {
                let at = y as usize * w as usize;
                let rendered = &painted[at + r.min.x as usize..=at + r.max.x as usize];
                let seen = view.row(y, r.min.x, r.max.x);
                let differs = |(v, p): (&Occ, &Option<Occ>)| *v != p.unwrap_or(Occ::Unknown);
                seen.iter().zip(rendered).filter(|&vp| differs(vp)).count()
            })
            .sum()
    }
}

/// e_avg (eq. 6.1) of the series `d` (one d_t per step) for `explored_cells` = g; 0 for an
/// empty series or g = 0.
pub fn average_error(d: &[usize], explored_cells: usize) -> f64 {
    if d.is_empty() || explored_cells == 0 {
        return 0.0;
    }
    let sum: f64 = d.iter().map(|&x| x as f64).sum();
    sum / (explored_cells as f64 * d.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::approximator::approximate;
    use crate::mapping::contour::Contours;

    #[test]
    fn exact_approximation_has_no_error() {
        let g = Grid::from_ascii("?????\n.###.\n..#..\n.....");
        let p = Contours::extract(&g);
        assert_eq!(approx_error(&g, &Approximation::exact(&p)), 0);
        assert_eq!(approx_error(&g, &approximate(&p, &g, usize::MAX)), 0);
    }

    #[test]
    fn coarse_approximation_has_error() {
        let g = Grid::from_ascii("......\n.####.\n.#....\n......");
        let p = Contours::extract(&g);
        assert!(approx_error(&g, &approximate(&p, &g, 0)) > 0);
    }

    proptest::proptest! {
        /// Counted only where the view or the approximation says something, d_t is the count
        /// over every cell.
        #[test]
        fn bounded_error_counts_every_cell(g in crate::testutil::arb_placed_grid(), splits in 0usize..8) {
            let a = approximate(&Contours::extract(&g), &g, splits);
            let view = exploration_view(&g);
            let polys: Vec<&Polygon> = a.objects.values().collect();
            let full = render_window(&polys, proto::grid::Cell::new(0, 0), g.width(), g.height());
            let every = view.cells().iter().zip(&full).filter(|(v, r)| v != r).count();
            proptest::prop_assert_eq!(approx_error_in_view(&view, &a), every);
        }
    }

    proptest::proptest! {
        /// Kept over steps in which G_s grows (its view kept from the changed cells) and the
        /// approximation changes in places, d_t is the count afresh at every step.
        #[test]
        fn the_kept_error_is_the_error_counted_afresh_at_every_step(
            steps in crate::testutil::arb_exploration(24, 5),
            s in proptest::prop_oneof![proptest::strategy::Just(0.0), proptest::strategy::Just(1.0), proptest::strategy::Just(4.0)],
        ) {
            let mut ax = crate::mapping::approximator::Approximator::new();
            let mut view = crate::mapping::render::ExplorationView::new(&steps[0]);
            let mut kept = KeptError::new(view.grid());
            let mut before = steps[0].clone();
            for g in &steps {
                let changed: Vec<proto::grid::Cell> = (0..g.len())
                    .filter(|&i| g.cells()[i] != before.cells()[i])
                    .map(|i| g.cell_of(i))
                    .collect();
                if let Some(r) = Rect::around(changed.iter().copied()).map(|r| r.grown(1)) {
                    kept.before_view(view.grid(), r);
                    view.update(g, changed.iter().copied());
                    kept.after_view(view.grid(), r);
                }
                let a = ax.step_in_view(&Contours::extract(g), view.grid(), s).clone();
                proptest::prop_assert_eq!(kept.error(view.grid(), &a), approx_error_in_view(view.grid(), &a));
                before = g.clone();
            }
        }
    }

    #[test]
    fn average_follows_eq_6_1() {
        assert_eq!(average_error(&[2, 4, 6], 10), 0.4);
        assert_eq!(average_error(&[], 10), 0.0);
        assert_eq!(average_error(&[3], 0), 0.0);
    }
}
