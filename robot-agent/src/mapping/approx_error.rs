//! The approximation error of thesis §6.1: d_t, the number of cells in which the
//! self-explored grid G_s and the grid rendered from the approximation A_t differ, and its
//! average e_avg = Σ_{t=1}^{n} d_t / (g · n) (eq. 6.1) over n steps and g explored cells.
//!
//! Interpretation: G_s is compared in its [`exploration_view`] — non-free cells with no free
//! 4-neighbour read unknown — because no contour model carries cells buried behind other
//! non-free cells (the thesis's own rendering fills them with unknown as well). So d_t is 0
//! for the unsimplified approximation and counts exactly what simplification loses or invents.
//! Both grids must share one frame.

use proto::grid::{Grid, Rect};

use crate::mapping::approx::{Approximation, Polygon};
use crate::mapping::render::{exploration_view, render_window};

/// d_t: cells where `own` (G_s, in its exploration view) and the rendering of `a` differ.
pub fn approx_error(own: &Grid, a: &Approximation) -> usize {
    approx_error_in_view(&exploration_view(own), a)
}

/// [`approx_error`] given G_s's exploration view (kept: [`crate::mapping::render::ExplorationView`]).
/// Compares only where either says something: the known part of the view and the cells the
/// approximation paints.
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

    #[test]
    fn average_follows_eq_6_1() {
        assert_eq!(average_error(&[2, 4, 6], 10), 0.4);
        assert_eq!(average_error(&[], 10), 0.0);
        assert_eq!(average_error(&[3], 0), 0.0);
    }
}
