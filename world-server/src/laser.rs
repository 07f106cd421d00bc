//! Simulated laser scans: exact ray casting through the truth grid.
//!
//! docs/design.md §3: every step the world-server casts `beams` rays over the sensor's `fov` up to
//! `max_range` against the truth map, with optional Gaussian range noise. Rays walk the grid
//! cell by cell with the Amanatides–Woo traversal, so no cell a ray crosses is skipped however
//! steep or long the ray. A ray stops at the first cell that is not free: unknown cells of real
//! maps block like walls (what was never seen by the map's author is treated as opaque and
//! impassable). The traversal is the workspace's one ([`proto::traverse`]). The reported range is the distance to where the ray *enters* that cell; a ray
//! that reaches `max_range_m` or leaves the grid reports `max_range_m`, meaning "no return" (the
//! convention of [`proto::msg::Scan`]). Where a ray passes exactly through a cell corner it
//! touches both side cells too, and either one blocks it — the same supercover rule robots move
//! by ([`crate::motion`]), so a beam never sees through a diagonal gap a robot cannot pass.

use proto::geom::{LaserSpec, MapInfo, Metres, Pose};
use proto::grid::{Cell, Grid, Occ};
use proto::traverse::{Corners, Crossing, Traversal};
use rand::{Rng, RngCore};

/// One scan from `pose`: a range in metres per beam, beam `i` at `pose.theta +
/// spec.beam_angle(i)`. With `rng`, hits get N(0, `noise_std_m`) noise, clamped to
/// `[0, max_range_m]`; "no return" ranges stay exactly `max_range_m`.
pub fn cast(
    grid: &Grid,
    info: &MapInfo,
    pose: Pose,
    spec: &LaserSpec,
    mut rng: Option<&mut dyn RngCore>,
) -> Vec<f32> {
    let max = spec.max_range_m;
    let noisy = spec.noise_std_m.is_finite() && spec.noise_std_m > 0.0;
    let mut ranges = Vec::with_capacity(spec.beams as usize);
    for i in 0..spec.beams {
        let angle = pose.theta + spec.beam_angle(i);
        let range = match (
            ray_hit_m(grid, info, pose.xy(), angle, max),
            rng.as_deref_mut(),
        ) {
            (Some(hit), Some(r)) if noisy => (hit + spec.noise_std_m * gaussian(r)).clamp(0.0, max),
            (Some(hit), _) => hit,
            (None, _) => max,
        };
        ranges.push(range as f32);
    }
    ranges
}

/// A standard normal sample by the Box–Muller transform.
fn gaussian(rng: &mut dyn RngCore) -> f64 {
    // `1 - u` lies in (0, 1], so the logarithm is finite.
    let u1 = 1.0 - rng.gen::<f64>();
    let u2 = rng.gen::<f64>();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Distance in metres from `p` along `angle` to the first non-free cell, if one is entered
/// before `max_range_m` and before the ray leaves the grid. A ray starting in a non-free cell hits
/// at 0; one starting outside the grid sees nothing.
pub fn ray_hit_m(
    grid: &Grid,
    info: &MapInfo,
    p: Metres,
    angle: f64,
    max_range_m: f64,
) -> Option<f64> {
    let res = info.resolution_m;
    if !(p.x.is_finite() && p.y.is_finite() && angle.is_finite() && res.is_finite() && res > 0.0) {
        return None;
    }
    if max_range_m.is_nan() || max_range_m <= 0.0 {
        return None;
    }
    let start = info.in_cells(p);
    let hit_cells = traverse(grid, start, (angle.cos(), angle.sin()), max_range_m / res)?;
    Some(hit_cells * res)
}

/// The grid traversal ([`proto::traverse`], supercover at exact corners) in cell units from `p`
/// along the unit vector `d`; returns the ray parameter (in cells) at which it enters the first
/// non-free cell, if that is before `max_t`.
fn traverse(grid: &Grid, p: (f64, f64), d: (f64, f64), max_t: f64) -> Option<f64> {
    let ray = Traversal::ray(p, d, Corners::Supercover { eps: 0.0 });
    if !grid.contains(ray.cell()) {
        return None;
    }
    if grid.get(ray.cell()) != Occ::Free {
        return Some(0.0);
    }
    let blocks = |c: Cell| grid.contains(c) && grid.get(c) != Occ::Free;
    // Each crossing enters a new cell; a ray inside the grid crosses at most width + height.
    for Crossing { t, cell, corner } in ray.take(grid.width() as usize + grid.height() as usize + 1)
    {
        if t.is_nan() || t >= max_t {
            return None;
        }
        // Exactly through a corner: the two side cells are touched as well.
        if corner.is_some_and(|sides| sides.into_iter().any(blocks)) {
            return Some(t);
        }
        if !grid.contains(cell) {
            return None;
        }
        if grid.get(cell) != Occ::Free {
            return Some(t);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use std::f64::consts::{FRAC_1_SQRT_2, FRAC_PI_2, PI, TAU};

    fn info(grid: &Grid, resolution_m: f64) -> MapInfo {
        MapInfo::at_origin(grid.width(), grid.height(), resolution_m)
    }

    fn spec(beams: u32, max_range_m: f64) -> LaserSpec {
        LaserSpec {
            beams,
            fov_rad: TAU,
            max_range_m,
            noise_std_m: 0.0,
        }
    }

    const BOX: &str = "
        ##########
        #........#
        #........#
        #........#
        ##########";

    fn close(a: f32, b: f64) -> bool {
        (f64::from(a) - b).abs() < 1e-4
    }

    #[test]
    fn axis_beams_hit_walls_at_the_cell_boundary() {
        let g = Grid::from_ascii(BOX);
        // Four beams at -π, -π/2, 0, π/2 from cell (2, 2)'s centre (0.25, 0.25).
        let r = cast(
            &g,
            &info(&g, 0.1),
            Pose {
                x: 0.25,
                y: 0.25,
                theta: 0.0,
            },
            &spec(4, 8.0),
            None,
        );
        let want = [0.15, 0.15, 0.65, 0.15];
        assert!(r.iter().zip(want).all(|(&a, b)| close(a, b)), "{r:?}");
        let origin = MapInfo {
            origin_x_m: -3.0,
            origin_y_m: 2.0,
            ..info(&g, 0.1)
        };
        let r = cast(
            &g,
            &origin,
            Pose {
                x: -2.75,
                y: 2.25,
                theta: FRAC_PI_2,
            },
            &spec(4, 8.0),
            None,
        );
        assert!(
            r.iter()
                .zip([0.15, 0.65, 0.15, 0.15])
                .all(|(&a, b)| close(a, b)),
            "{r:?}"
        );
    }

    #[test]
    fn diagonal_beams() {
        let mut g = Grid::new(12, 12, Occ::Free);
        g.set(Cell::new(6, 6), Occ::Occupied);
        let i = info(&g, 0.1);
        let at = |x, y, angle| ray_hit_m(&g, &i, Metres::new(x, y), angle, 8.0);
        // Through the corners (3,3), (4,4), (5,5) into the occupied cell.
        let hit = at(0.25, 0.25, PI / 4.0).unwrap_or(f64::NAN);
        assert!((hit - 3.5 * 2f64.sqrt() * 0.1).abs() < 1e-4, "{hit}");
        // Slope 1/2 from (2.5, 2.5) cells reaches the wall column x = 8 at y = 5.25.
        let mut wall = Grid::new(12, 12, Occ::Free);
        (0..12).for_each(|y| wall.set(Cell::new(8, y), Occ::Occupied));
        let hit =
            ray_hit_m(&wall, &i, Metres::new(0.25, 0.25), 0.5f64.atan(), 8.0).unwrap_or(f64::NAN);
        assert!((hit - 0.55 * 1.25f64.sqrt()).abs() < 1e-4, "{hit}");
        let back = ray_hit_m(&wall, &i, Metres::new(1.15, 0.55), PI - 0.5f64.atan(), 8.0)
            .unwrap_or(f64::NAN);
        assert!((back - 0.25 * 1.25f64.sqrt()).abs() < 1e-4, "{back}");
    }

    #[test]
    fn exact_corner_crossings_are_blocked_by_either_side_cell() {
        let g = Grid::from_ascii(
            "....\n\
             .#..\n\
             ....\n",
        );
        let d = (FRAC_1_SQRT_2, FRAC_1_SQRT_2);
        // From (0.5, 0.5) the ray passes exactly through the corner (1, 1) of the cell (1, 1).
        assert_eq!(traverse(&g, (0.5, 0.5), d, 10.0), Some(0.5 / FRAC_1_SQRT_2));
        // Only the side cell (1, 0) is occupied: the corner crossing still touches it.
        let side = Grid::from_ascii("....\n....\n.#..\n");
        assert_eq!(
            traverse(&side, (0.5, 0.5), d, 10.0),
            Some(0.5 / FRAC_1_SQRT_2)
        );
        let open = Grid::from_ascii("....\n....\n....\n");
        assert_eq!(traverse(&open, (0.5, 0.5), d, 10.0), None);
    }

    #[test]
    fn beams_leaving_the_map_or_out_of_range_report_max() {
        let g = Grid::new(20, 10, Occ::Free);
        let r = cast(
            &g,
            &info(&g, 0.1),
            Pose {
                x: 1.0,
                y: 0.5,
                theta: 0.3,
            },
            &spec(90, 8.0),
            None,
        );
        assert!(r.iter().all(|&x| x == 8.0), "{r:?}");
        let boxed = Grid::from_ascii(BOX);
        let short = cast(
            &boxed,
            &info(&boxed, 0.1),
            Pose {
                x: 0.25,
                y: 0.25,
                theta: 0.0,
            },
            &spec(4, 0.5),
            None,
        );
        assert_eq!(short[2], 0.5, "the east wall at 0.65 m is beyond 0.5 m");
    }

    #[test]
    fn closed_box_returns_every_beam_and_unknown_blocks() {
        let g = Grid::from_ascii("??????\n?....#\n?....#\n######\n");
        let r = cast(
            &g,
            &info(&g, 0.2),
            Pose {
                x: 0.5,
                y: 0.3,
                theta: 1.0,
            },
            &spec(360, 8.0),
            None,
        );
        assert_eq!(r.len(), 360);
        assert!(r.iter().all(|&x| x > 0.0 && x < 0.9), "{r:?}");
    }

    #[test]
    fn odd_poses() {
        let g = Grid::from_ascii(BOX);
        let i = info(&g, 0.1);
        let inside_wall = cast(
            &g,
            &i,
            Pose {
                x: 0.05,
                y: 0.05,
                theta: 0.0,
            },
            &spec(8, 8.0),
            None,
        );
        assert!(inside_wall.iter().all(|&x| x == 0.0));
        let outside = cast(
            &g,
            &i,
            Pose {
                x: -5.0,
                y: 0.05,
                theta: 0.0,
            },
            &spec(8, 8.0),
            None,
        );
        assert!(outside.iter().all(|&x| x == 8.0));
        let nan = cast(
            &g,
            &i,
            Pose {
                x: f64::NAN,
                y: 0.25,
                theta: 0.0,
            },
            &spec(8, 8.0),
            None,
        );
        assert!(nan.iter().all(|&x| x == 8.0));
        assert!(cast(&g, &i, Pose::default(), &spec(0, 8.0), None).is_empty());
    }

    #[test]
    fn noise_has_the_requested_spread_and_spares_no_returns() {
        let g = Grid::from_ascii(BOX);
        let i = info(&g, 0.1);
        let pose = Pose {
            x: 0.45,
            y: 0.25,
            theta: 0.0,
        };
        let exact = cast(&g, &i, pose, &spec(720, 8.0), None);
        let noisy_spec = LaserSpec {
            noise_std_m: 0.02,
            ..spec(720, 8.0)
        };
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let noisy = cast(&g, &i, pose, &noisy_spec, Some(&mut rng));
        let errs: Vec<f64> = noisy
            .iter()
            .zip(&exact)
            .map(|(&n, &e)| f64::from(n) - f64::from(e))
            .collect();
        let mean = errs.iter().sum::<f64>() / errs.len() as f64;
        let std = (errs.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errs.len() as f64).sqrt();
        assert!(
            mean.abs() < 0.004 && (std - 0.02).abs() < 0.004,
            "mean {mean}, std {std}"
        );
        assert!(noisy.iter().all(|&x| (0.0..=8.0).contains(&x)));
        let open = Grid::new(10, 10, Occ::Free);
        let none = cast(
            &open,
            &info(&open, 0.1),
            Pose {
                x: 0.5,
                y: 0.5,
                theta: 0.0,
            },
            &noisy_spec,
            Some(&mut rng),
        );
        assert!(none.iter().all(|&x| x == 8.0));
        let mut again = ChaCha8Rng::seed_from_u64(5);
        assert_eq!(
            cast(&g, &i, pose, &noisy_spec, Some(&mut again)),
            noisy,
            "same seed, same noise"
        );
    }

    #[test]
    fn corner_clipping_hit_is_the_clipped_cell() {
        // Found by the property test: the beam enters the occupied cell (0, 1) at x = 0.9956 cell
        // and leaves it through its right side 0.0099 cell later, into the free cell (1, 1).
        let g = Grid::from_ascii("...\n#..\n...\n");
        let i = info(&g, 0.2);
        let (x, y, angle) = (
            0.6034453778137109 * 0.2,
            0.22183393019343198 * 0.2,
            1.1040862664648514,
        );
        let hit = ray_hit_m(&g, &i, Metres::new(x, y), angle, 8.0).unwrap_or(f64::NAN);
        let want = (1.0 - 0.22183393019343198) / angle.sin() * 0.2;
        assert!((hit - want).abs() < 1e-12, "{hit} vs {want}");
        assert_eq!(
            i.cell_of(Metres::new(
                x + (hit + 1e-6) * angle.cos(),
                y + (hit + 1e-6) * angle.sin()
            )),
            Cell::new(0, 1)
        );
    }

    fn arb_grid() -> impl Strategy<Value = Grid> {
        (3u32..16, 3u32..16).prop_flat_map(|(w, h)| {
            prop::collection::vec(
                prop::sample::select(vec![
                    Occ::Free,
                    Occ::Free,
                    Occ::Free,
                    Occ::Occupied,
                    Occ::Unknown,
                ]),
                (w * h) as usize,
            )
            .prop_map(move |cells| {
                let mut g = Grid::new(w, h, Occ::Free);
                g.cells_mut().copy_from_slice(&cells);
                g
            })
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]
        #[test]
        fn range_ends_exactly_at_the_first_blocking_cell(
            g in arb_grid(),
            fx in 0.0f64..1.0,
            fy in 0.0f64..1.0,
            angle in -PI..PI,
            max in 0.1f64..3.0,
            pick in any::<prop::sample::Index>(),
        ) {
            let res = 0.2;
            let i = info(&g, res);
            let free: Vec<Cell> = (0..g.len()).map(|k| g.cell_of(k)).filter(|&c| g.get(c) == Occ::Free).collect();
            prop_assume!(!free.is_empty());
            let c = free[pick.index(free.len())];
            let (x, y) = ((f64::from(c.x) + fx) * res, (f64::from(c.y) + fy) * res);
            let range = ray_hit_m(&g, &i, Metres::new(x, y), angle, max).unwrap_or(max);
            let at = |s: f64| i.cell_of(Metres::new(x + s * angle.cos(), y + s * angle.sin()));
            if range < max {
                // Just beyond: a ray that clips the corner of the blocking cell may cross it in
                // less than 0.01 cell, so the probe is much closer than that (it is regression
                // `corner_clipping_hit_is_the_clipped_cell`).
                prop_assert_ne!(g.get(at(range + 1e-6 * res)), Occ::Free);
                prop_assert!(g.contains(at(range + 1e-6 * res)));
            }
            let before = (range - 1e-6 * res).max(0.0);
            for k in 0..=200 {
                let cell = at(before * f64::from(k) / 200.0);
                prop_assert!(!g.contains(cell) || g.get(cell) == Occ::Free, "cell {:?} before the hit", cell);
            }
        }
    }
}
