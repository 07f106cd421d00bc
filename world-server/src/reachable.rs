//! Connected free space: the reachable region of a map, its largest free component, clearance to
//! obstacles, and where to spawn a cluster of robots.
//!
//! docs/design.md §3 spawns robots by default "as a cluster in one free area, all in the same
//! connected free region", and §6 measures exploration against "the truth's reachable free
//! cells" — the cells the robots can reach by the one rule of reachability
//! ([`proto::grid::Grid::reachable`]: free cells 4-connected to the robots, because robots move
//! along segments that may not squeeze through a diagonal gap between two blocked cells, see
//! [`crate::motion`]). Map generation ([`crate::generate`]) uses the largest such region, to
//! guarantee one free region.

use proto::geom::MapInfo;
use proto::grid::{Cell, Grid, Occ};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SpawnError {
    #[error("the map has no free cell to spawn on")]
    NoFreeSpace,
    #[error(
        "map info says {info_width}x{info_height} cells, the grid has {grid_width}x{grid_height}"
    )]
    MapMismatch {
        info_width: u32,
        info_height: u32,
        grid_width: u32,
        grid_height: u32,
    },
    #[error("spawn parameter {name} = {value} is out of range (finite, ≥ 0; resolution > 0)")]
    BadParameter { name: &'static str, value: f64 },
    #[error("only {placed} of {wanted} robots fit {spacing_m} m apart in the largest free region ({cells} cells)")]
    NotEnoughRoom {
        wanted: usize,
        placed: usize,
        spacing_m: f64,
        cells: usize,
    },
}

/// A grid of the same size whose free cells are the cells reachable from any seed
/// ([`Grid::reachable`], the one rule the robots' planner follows too); every other cell is
/// unknown.
pub fn reachable_free(grid: &Grid, seeds: &[Cell]) -> Grid {
    let mut out = Grid::new(grid.width(), grid.height(), Occ::Unknown);
    for (o, reached) in out.cells_mut().iter_mut().zip(grid.reachable(seeds)) {
        if reached {
            *o = Occ::Free;
        }
    }
    out
}

/// Membership mask of the largest 4-connected free component (ties: the one whose first cell
/// comes first in row-major order); all false when there is no free cell.
pub fn largest_free_mask(grid: &Grid) -> Vec<bool> {
    let mut seen = vec![false; grid.len()];
    let mut best: Option<(Cell, usize)> = None;
    for start in 0..grid.len() {
        if grid.cells()[start] != Occ::Free || seen[start] {
            continue;
        }
        let c = grid.cell_of(start);
        let size = grid.reach_into(&[c], &mut seen);
        if best.is_none_or(|(_, most)| size > most) {
            best = Some((c, size));
        }
    }
    best.map_or_else(|| vec![false; grid.len()], |(c, _)| grid.reachable(&[c]))
}

/// The cells of the largest 4-connected free component, in row-major order.
pub fn largest_free_component(grid: &Grid) -> Vec<Cell> {
    let mask = largest_free_mask(grid);
    (0..grid.len())
        .filter(|&i| mask[i])
        .map(|i| grid.cell_of(i))
        .collect()
}

/// Squared distances (in cells, centre to centre) from every cell to the nearest cell that is
/// not free; cells outside the grid count as not free.
///
/// The exact Euclidean distance transform of Felzenszwalb & Huttenlocher: a lower envelope of
/// parabolas per column, then per row, linear in the number of cells.
pub fn squared_clearance_cells(grid: &Grid) -> Vec<f64> {
    // Pad by one blocked cell on every side so that the map edge is an obstacle.
    let (w, h) = (grid.width() as usize + 2, grid.height() as usize + 2);
    let mut d: Vec<f64> = (0..w * h)
        .map(|i| {
            let c = Cell::new((i % w) as i32 - 1, (i / w) as i32 - 1);
            if grid.get(c) == Occ::Free {
                f64::INFINITY
            } else {
                0.0
            }
        })
        .collect();
    let mut line = Vec::new();
    for x in 0..w {
        line.clear();
        line.extend((0..h).map(|y| d[y * w + x]));
        for (y, v) in edt_1d(&line).into_iter().enumerate() {
            d[y * w + x] = v;
        }
    }
    for y in 0..h {
        let row = edt_1d(&d[y * w..(y + 1) * w]);
        d[y * w..(y + 1) * w].copy_from_slice(&row);
    }
    let mut out = Vec::with_capacity(grid.len());
    for y in 1..h - 1 {
        out.extend_from_slice(&d[y * w + 1..y * w + w - 1]);
    }
    out
}

/// One-dimensional squared distance transform of a sampled function `f` (0 at obstacles,
/// infinity elsewhere, or the result of a previous pass).
fn edt_1d(f: &[f64]) -> Vec<f64> {
    let n = f.len();
    let mut out = vec![f64::INFINITY; n];
    // Parabola apexes `v` and the boundaries `z` between them in the lower envelope.
    let mut v = vec![0usize; n];
    let mut z = vec![0f64; n + 1];
    let mut k = 0;
    let Some(first) = f.iter().position(|x| x.is_finite()) else {
        return out;
    };
    v[0] = first;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    let meet = |q: usize, p: usize| {
        let (q2, p2) = ((q * q) as f64, (p * p) as f64);
        ((f[q] + q2) - (f[p] + p2)) / (2.0 * (q as f64 - p as f64))
    };
    for (q, fq) in f.iter().enumerate().skip(first + 1) {
        if !fq.is_finite() {
            continue;
        }
        let mut s = meet(q, v[k]);
        while s <= z[k] {
            k -= 1;
            s = meet(q, v[k]);
        }
        k += 1;
        v[k] = q;
        z[k] = s;
        z[k + 1] = f64::INFINITY;
    }
    k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let dq = q as f64 - v[k] as f64;
        *o = dq * dq + f[v[k]];
    }
    out
}

/// Picks spawn cells for `count` robots: one anchor in the largest free component (a random cell
/// with at least `clearance_m` to the nearest non-free cell, else the most open cell), then cells
/// of that component in breadth-first order from the anchor, pairwise at least `spacing_m` apart
/// (centre to centre). Cells as open as the anchor (up to `clearance_m`) are taken first.
pub fn spawn_cluster(
    grid: &Grid,
    info: &MapInfo,
    count: usize,
    spacing_m: f64,
    clearance_m: f64,
    seed: u64,
) -> Result<Vec<Cell>, SpawnError> {
    check_spawn_inputs(grid, info, spacing_m, clearance_m)?;
    let mask = largest_free_mask(grid);
    let component: Vec<usize> = (0..grid.len()).filter(|&i| mask[i]).collect();
    if component.is_empty() {
        return Err(SpawnError::NoFreeSpace);
    }
    // Clearance in metres from a cell's centre to the nearest edge of a non-free cell.
    let clearance: Vec<f64> = squared_clearance_cells(grid)
        .iter()
        .map(|d2| (d2.sqrt() - 0.5) * info.resolution_m)
        .collect();
    let anchor = spawn_anchor(&component, &clearance, clearance_m, seed);
    let order = bfs_order(grid, &mask, anchor);
    let threshold = clearance_m.min(clearance[anchor]);
    let mut chosen: Vec<Cell> = Vec::with_capacity(count);
    for pass_threshold in [threshold, f64::NEG_INFINITY] {
        for &i in &order {
            if chosen.len() == count {
                return Ok(chosen);
            }
            let c = grid.cell_of(i);
            let far = |o: &Cell| {
                let (dx, dy) = (f64::from(o.x - c.x), f64::from(o.y - c.y));
                (dx * dx + dy * dy).sqrt() * info.resolution_m >= spacing_m - 1e-9
            };
            if clearance[i] >= pass_threshold && !chosen.contains(&c) && chosen.iter().all(far) {
                chosen.push(c);
            }
        }
    }
    if chosen.len() == count {
        return Ok(chosen);
    }
    Err(SpawnError::NotEnoughRoom {
        wanted: count,
        placed: chosen.len(),
        spacing_m,
        cells: component.len(),
    })
}

/// Checks that `info` describes `grid` and the spacing, clearance and resolution are in range.
fn check_spawn_inputs(
    grid: &Grid,
    info: &MapInfo,
    spacing_m: f64,
    clearance_m: f64,
) -> Result<(), SpawnError> {
    if (info.width, info.height) != (grid.width(), grid.height()) {
        return Err(SpawnError::MapMismatch {
            info_width: info.width,
            info_height: info.height,
            grid_width: grid.width(),
            grid_height: grid.height(),
        });
    }
    for (name, value) in [
        ("spacing_m", spacing_m),
        ("clearance_m", clearance_m),
        ("resolution_m", info.resolution_m),
    ] {
        let positive = value > 0.0 || (value == 0.0 && name != "resolution_m");
        if !(value.is_finite() && positive) {
            return Err(SpawnError::BadParameter { name, value });
        }
    }
    Ok(())
}

/// The cluster's anchor: a seeded random cell with `clearance_m`, else the first most open one.
fn spawn_anchor(component: &[usize], clearance: &[f64], clearance_m: f64, seed: u64) -> usize {
    let open: Vec<usize> = component
        .iter()
        .copied()
        .filter(|&i| clearance[i] >= clearance_m)
        .collect();
    if open.is_empty() {
        // The first most open cell: `max_by` would return the last of equals.
        component.iter().copied().fold(component[0], |b, i| {
            if clearance[i] > clearance[b] {
                i
            } else {
                b
            }
        })
    } else {
        open[ChaCha8Rng::seed_from_u64(seed).gen_range(0..open.len())]
    }
}

/// Indices of the masked cells in breadth-first (4-neighbour) order from `start`.
fn bfs_order(grid: &Grid, mask: &[bool], start: usize) -> Vec<usize> {
    let mut seen = vec![false; grid.len()];
    let mut order = vec![start];
    seen[start] = true;
    let mut head = 0;
    while let Some(&i) = order.get(head) {
        head += 1;
        for n in grid.cell_of(i).neighbours4() {
            if let Some(j) = grid.index(n).filter(|&j| mask[j] && !seen[j]) {
                seen[j] = true;
                order.push(j);
            }
        }
    }
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info(grid: &Grid, resolution_m: f64) -> MapInfo {
        MapInfo::at_origin(grid.width(), grid.height(), resolution_m)
    }

    const TWO_ROOMS: &str = "
        #########
        #...#...#
        #...#....
        #...#...#
        #########";

    #[test]
    fn reachable_free_keeps_only_the_seeded_region() {
        let g = Grid::from_ascii(TWO_ROOMS);
        let r = reachable_free(&g, &[Cell::new(1, 1)]);
        assert_eq!(
            r.to_ascii(),
            "?????????\n?...?????\n?...?????\n?...?????\n?????????\n"
        );
        let both = reachable_free(
            &g,
            &[
                Cell::new(1, 1),
                Cell::new(6, 2),
                Cell::new(0, 0),
                Cell::new(-3, 9),
            ],
        );
        assert_eq!(both.count(Occ::Free), g.count(Occ::Free));
        assert_eq!(reachable_free(&g, &[]).count(Occ::Free), 0);
    }

    #[test]
    fn diagonal_contact_does_not_connect() {
        let g = Grid::from_ascii(".#\n#.\n");
        assert_eq!(reachable_free(&g, &[Cell::new(0, 1)]).count(Occ::Free), 1);
        assert_eq!(
            largest_free_component(&g),
            vec![Cell::new(1, 0)],
            "ties go to the first in row order"
        );
    }

    #[test]
    fn largest_component_is_the_right_room() {
        let g = Grid::from_ascii(TWO_ROOMS);
        let big = largest_free_component(&g);
        assert_eq!(big.len(), 10);
        assert!(big.iter().all(|c| c.x >= 5));
        assert!(largest_free_component(&Grid::from_ascii("#?\n")).is_empty());
    }

    #[test]
    fn clearance_is_the_euclidean_distance_to_the_nearest_blocked_cell() {
        let g = Grid::from_ascii(
            "......\n\
             ......\n\
             ..#...\n\
             ......\n",
        );
        let d = squared_clearance_cells(&g);
        let at = |x, y| d[g.index(Cell::new(x, y)).unwrap_or(0)];
        assert_eq!(at(2, 1), 0.0);
        assert_eq!(at(3, 1), 1.0);
        assert_eq!(at(3, 2), 2.0, "diagonal to the obstacle");
        assert_eq!(at(4, 2), 4.0, "two rows below the map's top edge");
        assert_eq!(at(3, 0), 1.0, "the map edge blocks");
        assert_eq!(at(2, 2), 1.0);
        let open = Grid::from_ascii(".....\n.....\n.....\n.....\n.....\n");
        assert_eq!(
            squared_clearance_cells(&open)[open.index(Cell::new(2, 2)).unwrap_or(0)],
            9.0
        );
    }

    #[test]
    fn spawn_cluster_is_spaced_connected_and_deterministic() {
        let g = Grid::from_ascii(
            "##########\n\
             #........#\n\
             #........#\n\
             #........#\n\
             #........#\n\
             ##########\n\
             #..#######\n\
             ##########\n",
        );
        let i = info(&g, 0.5);
        let cells = spawn_cluster(&g, &i, 4, 1.0, 0.75, 7).expect("room for four");
        assert_eq!(cells.len(), 4);
        let region = reachable_free(&g, &cells[..1]);
        for (k, a) in cells.iter().enumerate() {
            assert_eq!(region.get(*a), Occ::Free, "all in the same free region");
            for b in &cells[k + 1..] {
                let d = a.dist(*b) * 0.5;
                assert!(d >= 1.0 - 1e-9, "{a:?} and {b:?} are {d} m apart");
            }
        }
        assert_eq!(spawn_cluster(&g, &i, 4, 1.0, 0.75, 7), Ok(cells));
        assert_eq!(spawn_cluster(&g, &i, 0, 1.0, 0.75, 7), Ok(vec![]));
    }

    #[test]
    fn spawn_falls_back_to_the_most_open_cell() {
        // No cell has 5 m of clearance; the anchor is the most open one, in the middle.
        let g = Grid::from_ascii("#######\n#.....#\n#.....#\n#.....#\n#.....#\n#.....#\n#######\n");
        let cells = spawn_cluster(&g, &info(&g, 1.0), 1, 1.0, 5.0, 3).expect("one robot fits");
        assert_eq!(cells, vec![Cell::new(3, 3)]);
    }

    #[test]
    fn spawn_errors() {
        let g = Grid::from_ascii("###\n#..\n###\n");
        let i = info(&g, 1.0);
        assert_eq!(
            spawn_cluster(&g, &i, 3, 1.0, 0.0, 0),
            Err(SpawnError::NotEnoughRoom {
                wanted: 3,
                placed: 2,
                spacing_m: 1.0,
                cells: 2
            })
        );
        assert_eq!(
            spawn_cluster(
                &Grid::from_ascii("#?\n"),
                &info(&Grid::from_ascii("#?\n"), 1.0),
                1,
                1.0,
                0.0,
                0
            ),
            Err(SpawnError::NoFreeSpace)
        );
        assert!(matches!(
            spawn_cluster(&g, &i, 1, f64::NAN, 0.0, 0),
            Err(SpawnError::BadParameter {
                name: "spacing_m",
                ..
            })
        ));
        assert!(matches!(
            spawn_cluster(&g, &i, 1, 1.0, -1.0, 0),
            Err(SpawnError::BadParameter {
                name: "clearance_m",
                ..
            })
        ));
        let flat = MapInfo {
            resolution_m: 0.0,
            ..i
        };
        assert!(matches!(
            spawn_cluster(&g, &flat, 1, 1.0, 0.0, 0),
            Err(SpawnError::BadParameter {
                name: "resolution_m",
                ..
            })
        ));
        let wrong = MapInfo { width: 4, ..i };
        assert!(matches!(
            spawn_cluster(&g, &wrong, 1, 1.0, 0.0, 0),
            Err(SpawnError::MapMismatch { .. })
        ));
    }

    #[test]
    fn spawn_in_a_generated_office_stays_in_one_region() {
        use crate::generate::generate;
        use proto::scenario::GeneratedWorld;
        for seed in 0..10 {
            let map = generate(GeneratedWorld::Office, 30.0, 20.0, 0.1, seed).expect("valid size");
            let cells =
                spawn_cluster(&map.grid, &map.info, 8, 1.0, 0.6, seed).expect("room for eight");
            let region = reachable_free(&map.grid, &cells[..1]);
            assert!(
                cells.iter().all(|&c| region.get(c) == Occ::Free),
                "seed {seed}"
            );
            let spread = cells
                .iter()
                .map(|c| f64::from((c.x - cells[0].x).abs().max((c.y - cells[0].y).abs())))
                .fold(0.0, f64::max);
            assert!(
                spread * 0.1 < 10.0,
                "seed {seed}: a cluster, not scattered ({spread} cells)"
            );
        }
    }
}
