//! Test fixtures shared by the mapping modules: random grids, windows cut from real maps
//! (ROS `map_server` PGM), and brute-force geometric checks for polygons in quarter cells.

use std::path::PathBuf;
use std::sync::OnceLock;

use proptest::prelude::*;
use proto::grid::{Cell, Grid, Occ};

use crate::mapping::qpoint::QPoint;

/// What the world-server tells robots of a world of frame `map` with `robots` robots in
/// scenario `s`.
pub fn world_info(
    s: &proto::scenario::Scenario,
    map: proto::geom::MapInfo,
    robots: u16,
) -> proto::msg::WorldInfo {
    proto::msg::WorldInfo {
        map,
        laser: s.laser(),
        step_seconds: s.clock.step_seconds,
        robots,
        max_speed_m_per_s: s.robots.speed_m_per_s,
    }
}

/// Random grids up to `max` × `max`, with a bias toward free cells so regions form.
pub fn arb_grid(max: u32) -> impl Strategy<Value = Grid> {
    (1..=max, 1..=max, 0u8..4).prop_flat_map(|(w, h, bias)| {
        proptest::collection::vec(0u8..10, (w * h) as usize).prop_map(move |v| {
            let mut g = Grid::new(w, h, Occ::Unknown);
            for (c, r) in g.cells_mut().iter_mut().zip(v) {
                *c = match r {
                    r if r < 5 + bias => Occ::Free,
                    r if r < 8 => Occ::Occupied,
                    _ => Occ::Unknown,
                };
            }
            g
        })
    })
}

/// Every shipped map in `configs/maps` (loaded once per test binary, with the world-server's
/// own ROS map loader, so PGM and PNG maps alike).
pub fn maps() -> &'static [Grid] {
    static MAPS: OnceLock<Vec<Grid>> = OnceLock::new();
    MAPS.get_or_init(|| {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../configs/maps");
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
            .unwrap_or_default();
        files.retain(|p| p.extension().is_some_and(|e| e == "yaml"));
        files.sort();
        let maps: Vec<Grid> = files
            .iter()
            .map(|p| {
                world_server::map::load_ros_map(p)
                    .unwrap_or_else(|e| panic!("{e}"))
                    .grid
            })
            .collect();
        assert!(!maps.is_empty(), "no maps in {}", dir.display());
        maps
    })
}

/// A `w × h` window of a real map at a random place.
pub fn arb_map_window(w: u32, h: u32) -> BoxedStrategy<Grid> {
    let n = maps().len();
    (0..n, any::<u32>(), any::<u32>())
        .prop_map(move |(m, ox, oy)| window(&maps()[m], w, h, ox, oy))
        .boxed()
}

/// The window at offsets `ox`, `oy` (wrapped into the map).
pub fn window(map: &Grid, w: u32, h: u32, ox: u32, oy: u32) -> Grid {
    let (w, h) = (w.min(map.width()), h.min(map.height()));
    let ox = ox % (map.width() - w + 1);
    let oy = oy % (map.height() - h + 1);
    let mut g = Grid::new(w, h, Occ::Unknown);
    for y in 0..h as i32 {
        for x in 0..w as i32 {
            g.set(
                Cell::new(x, y),
                map.get(Cell::new(x + ox as i32, y + oy as i32)),
            );
        }
    }
    g
}

/// `g` placed with its bottom-left cell at `at` in a `width × height` grid of unknown cells,
/// cell by cell, so that the bigger grid knows its explored part is only `g`'s (cells of `g`
/// beyond the bigger grid are left out).
pub fn placed(g: &Grid, width: u32, height: u32, at: Cell) -> Grid {
    let mut out = Grid::new(width, height, Occ::Unknown);
    if let Some(r) = g.whole() {
        for c in r.cells() {
            out.set(Cell::new(c.x + at.x, c.y + at.y), g.get(c));
        }
    }
    out
}

/// A random grid (up to 12 × 12) placed somewhere in a grid of up to 40 × 40 cells
/// ([`placed`]): a small explored part of a bigger map.
pub fn arb_placed_grid() -> impl Strategy<Value = Grid> {
    (arb_grid(12), 12u32..40, 12u32..40, 0i32..40, 0i32..40)
        .prop_map(|(g, w, h, x, y)| placed(&g, w, h, Cell::new(x % w as i32, y % h as i32)))
}

fn orient(a: QPoint, b: QPoint, c: QPoint) -> i64 {
    let (abx, aby) = (i64::from(b.x - a.x), i64::from(b.y - a.y));
    let (acx, acy) = (i64::from(c.x - a.x), i64::from(c.y - a.y));
    (abx * acy - aby * acx).signum()
}

fn on_segment(a: QPoint, b: QPoint, p: QPoint) -> bool {
    orient(a, b, p) == 0
        && p.x >= a.x.min(b.x)
        && p.x <= a.x.max(b.x)
        && p.y >= a.y.min(b.y)
        && p.y <= a.y.max(b.y)
}

/// Whether closed segments `a`–`b` and `c`–`d` share any point.
pub fn segments_meet(a: QPoint, b: QPoint, c: QPoint, d: QPoint) -> bool {
    let (o1, o2, o3, o4) = (
        orient(a, b, c),
        orient(a, b, d),
        orient(c, d, a),
        orient(c, d, b),
    );
    (o1 * o2 < 0 && o3 * o4 < 0)
        || on_segment(a, b, c)
        || on_segment(a, b, d)
        || on_segment(c, d, a)
        || on_segment(c, d, b)
}

/// Whether a closed polygon is simple: adjacent edges meet only in their shared vertex and
/// other edges do not meet at all. Returns the first offending pair of edge indices.
pub fn self_intersection(p: &[QPoint]) -> Option<(usize, usize)> {
    let n = p.len();
    for i in 0..n {
        let (a, b) = (p[i], p[(i + 1) % n]);
        for j in i + 1..n {
            let (c, d) = (p[j], p[(j + 1) % n]);
            let adjacent = j == i + 1 || (i == 0 && j == n - 1);
            let bad = if n < 3 || a == b {
                true
            } else if adjacent {
                // The edges share one vertex; neither's other end may lie on the other edge.
                let (x, y) = if j == i + 1 { (a, d) } else { (b, c) };
                on_segment(c, d, x) || on_segment(a, b, y)
            } else {
                segments_meet(a, b, c, d)
            };
            if bad {
                return Some((i, j));
            }
        }
    }
    None
}

/// Whether two closed polygons share any point of their boundaries.
pub fn polygons_meet(p: &[QPoint], q: &[QPoint]) -> bool {
    let (n, m) = (p.len(), q.len());
    (0..n).any(|i| (0..m).any(|j| segments_meet(p[i], p[(i + 1) % n], q[j], q[(j + 1) % m])))
}

/// Winding number of a closed polygon around `q` (q must not lie on the boundary).
pub fn winding(p: &[QPoint], q: QPoint) -> i32 {
    let n = p.len();
    let mut w = 0;
    for i in 0..n {
        let (a, b) = (p[i], p[(i + 1) % n]);
        if a.y <= q.y && b.y > q.y && orient(a, b, q) > 0 {
            w += 1;
        } else if a.y > q.y && b.y <= q.y && orient(a, b, q) < 0 {
            w -= 1;
        }
    }
    w
}

#[test]
fn shipped_maps_load() {
    let m = maps();
    assert_eq!(m.len(), 8, "expected the eight shipped maps");
    assert!(m
        .iter()
        .all(|g| g.count(Occ::Free) > 0 && g.count(Occ::Occupied) > 0));
}

/// A growing self-explored grid: the truth revealed rectangle by rectangle (one per step),
/// from either a random grid or a real map window.
pub fn arb_exploration(size: u32, steps: usize) -> impl Strategy<Value = Vec<Grid>> {
    let truth = prop_oneof![arb_grid(size), arb_map_window(size, size)];
    let rect = (0..size, 0..size, 1..=size / 2 + 1, 1..=size / 2 + 1);
    (truth, proptest::collection::vec(rect, 1..=steps)).prop_map(|(truth, rects)| {
        let mut g = Grid::new(truth.width(), truth.height(), Occ::Unknown);
        rects
            .into_iter()
            .map(|(x0, y0, w, h)| {
                for y in y0 as i32..(y0 + h) as i32 {
                    for x in x0 as i32..(x0 + w) as i32 {
                        g.set(Cell::new(x, y), truth.get(Cell::new(x, y)));
                    }
                }
                g.clone()
            })
            .collect()
    })
}

/// Independent random grids of one size: the harshest change between steps.
pub fn arb_grid_sequence(size: u32, steps: usize) -> impl Strategy<Value = Vec<Grid>> {
    proptest::collection::vec(arb_grid(size), 1..=steps).prop_map(move |gs| {
        gs.iter()
            .map(|g| window(g, size, size, 0, 0))
            .map(|g| pad_to(&g, size))
            .collect()
    })
}

fn pad_to(g: &Grid, size: u32) -> Grid {
    let mut out = Grid::new(size, size, Occ::Unknown);
    for y in 0..g.height() as i32 {
        for x in 0..g.width() as i32 {
            out.set(Cell::new(x, y), g.get(Cell::new(x, y)));
        }
    }
    out
}

/// One robot exploring `truth`: from the free cell nearest the centre it random-walks (seeded)
/// and casts 180 rays of `range` cells per step; returns G_s after every step.
pub fn explore(truth: &Grid, steps: usize, range: i32, seed: u64) -> Vec<Grid> {
    let (w, h) = (truth.width() as i32, truth.height() as i32);
    let centre = |c: &Cell| (c.x - w / 2).abs() + (c.y - h / 2).abs();
    let free: Vec<Cell> = (0..truth.len())
        .map(|i| truth.cell_of(i))
        .filter(|&c| truth.get(c) == Occ::Free)
        .collect();
    let Some(mut pos) = free.iter().copied().min_by_key(centre) else {
        return Vec::new();
    };
    let mut rng = seed | 1;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        rng
    };
    let (mut own, mut dir, mut out) = (
        Grid::new(truth.width(), truth.height(), Occ::Unknown),
        0usize,
        Vec::new(),
    );
    for _ in 0..steps {
        for k in 0..180 {
            let a = k as f64 * std::f64::consts::TAU / 180.0;
            for r in 0..4 * range {
                let f = f64::from(r) / 4.0;
                let c = Cell::new(
                    pos.x + (a.cos() * f).round() as i32,
                    pos.y + (a.sin() * f).round() as i32,
                );
                let v = truth.get(c);
                if v == Occ::Unknown {
                    break;
                }
                own.set(c, v);
                if v == Occ::Occupied {
                    break;
                }
            }
        }
        for _ in 0..4 {
            let n = pos.neighbours4()[dir];
            if truth.get(n) == Occ::Free && next() % 16 != 0 {
                pos = n;
            } else {
                dir = (next() % 4) as usize;
            }
        }
        out.push(own.clone());
    }
    out
}
