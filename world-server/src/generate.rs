//! Seeded map generators: `unstructured` (scattered obstacles, outdoor-like), `office` (rooms
//! and corridors, no furniture) and `mixed` (a building amid scattered obstacles); Simmons et
//! al.'s `corridor`, `two-corridors`, `empty` and `random`; and `library` (rows of shelves in a
//! hall ringed by rooms, in `library`).
//!
//! docs/design.md §3 lets a scenario generate its truth map from a seed instead of loading one,
//! with the three environment types of the thesis's experiments. A generated map is a closed world:
//! an outer wall, everything else occupied or free (no unknown), and all free cells one 4-connected
//! region, so that "explored everything reachable" is well defined. Two rules make that hold by
//! construction: obstacles keep a gap of more than [`PASSAGE_M`](crate::generate::PASSAGE_M) to
//! everything else (so they are islands), and every room has a door at least
//! [`DOOR_M`](crate::generate::DOOR_M) wide onto a corridor that the corridor spines connect. A
//! final pass then enforces both guarantees on whatever was built: free cells not inside any free
//! `PASSAGE_M`-square become occupied (no slivers narrower than a robot's passage), and free cells
//! outside the largest component become occupied. The same seed always gives the same map
//! (`ChaCha8Rng`, no other source of randomness).

use proto::geom::MapInfo;
use proto::grid::{Cell, Grid, Occ, MAX_CELLS};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use proto::scenario::GeneratedWorld;

use crate::map::TruthMap;

mod library;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GenError {
    #[error("{0}")]
    UnknownKind(String),
    #[error("resolution {resolution_m} m must be a positive finite number")]
    BadResolution { resolution_m: f64 },
    #[error("a generated map of {width_m} x {height_m} m at {resolution_m} m/cell is too small (at least {MIN_SIDE_M} m and a {DOOR_M} m door inside its walls)")]
    TooSmall {
        width_m: f64,
        height_m: f64,
        resolution_m: f64,
    },
    #[error("a generated map of {width} x {height} cells exceeds the limit of {MAX_CELLS} cells")]
    TooLarge { width: u64, height: u64 },
}

/// Narrowest free passage a generated map may contain.
pub const PASSAGE_M: f64 = 0.8;
/// Width of every door.
pub const DOOR_M: f64 = 1.0;
/// Thickness of walls.
const WALL_M: f64 = 0.2;
/// Shortest side of a generated map.
pub const MIN_SIDE_M: f64 = 3.0;

/// Sizes in cells, derived once from the resolution.
struct Params {
    res: f64,
    wall: i32,
    door: i32,
    passage: i32,
}

impl Params {
    /// A length in whole cells (at least one).
    fn cells(&self, m: f64) -> i32 {
        (m / self.res).round().max(1.0) as i32
    }
}

/// Half-open cell rectangle `[x0, x1) × [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Rect {
    x0: i32,
    y0: i32,
    x1: i32,
    y1: i32,
}

impl Rect {
    fn new(x0: i32, y0: i32, x1: i32, y1: i32) -> Rect {
        Rect { x0, y0, x1, y1 }
    }
    fn w(&self) -> i32 {
        self.x1 - self.x0
    }
    fn h(&self) -> i32 {
        self.y1 - self.y0
    }
    fn grow(&self, d: i32) -> Rect {
        Rect::new(self.x0 - d, self.y0 - d, self.x1 + d, self.y1 + d)
    }
}

fn fill(g: &mut Grid, r: Rect, v: Occ) {
    for y in r.y0..r.y1 {
        for x in r.x0..r.x1 {
            g.set(Cell::new(x, y), v);
        }
    }
}

/// True when every cell of `r` is inside the grid and free.
fn all_free(g: &Grid, r: Rect) -> bool {
    (r.y0..r.y1).all(|y| (r.x0..r.x1).all(|x| g.get(Cell::new(x, y)) == Occ::Free))
}

/// A uniform integer in `lo..=hi`, or `lo` when the range is empty.
fn between(rng: &mut ChaCha8Rng, lo: i32, hi: i32) -> i32 {
    if hi <= lo {
        lo
    } else {
        rng.gen_range(lo..=hi)
    }
}

/// Generates a `width_m × height_m` map of `kind` at `resolution_m`, origin (0, 0).
pub fn generate(
    kind: GeneratedWorld,
    width_m: f64,
    height_m: f64,
    resolution_m: f64,
    seed: u64,
) -> Result<TruthMap, GenError> {
    let (p, w, h) = sizes(width_m, height_m, resolution_m)?;
    let mut g = Grid::new(w as u32, h as u32, Occ::Occupied);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let interior = Rect::new(p.wall, p.wall, w - p.wall, h - p.wall);
    build(kind, &mut g, &mut rng, &p, interior);
    open_free(&mut g, p.passage);
    close_off_unreachable(&mut g);
    let info = MapInfo::at_origin(g.width(), g.height(), resolution_m);
    Ok(TruthMap { info, grid: g })
}

/// The [`Params`], width and height in cells of a map, or why it cannot be generated that size.
fn sizes(width_m: f64, height_m: f64, resolution_m: f64) -> Result<(Params, i32, i32), GenError> {
    if !(resolution_m.is_finite() && resolution_m > 0.0) {
        return Err(GenError::BadResolution { resolution_m });
    }
    let res = resolution_m;
    let p = Params {
        res,
        wall: 0,
        door: (DOOR_M / res - 1e-9).ceil().max(1.0) as i32,
        passage: 0,
    };
    let p = Params {
        wall: p.cells(WALL_M),
        passage: (PASSAGE_M / res - 1e-9).ceil().max(1.0) as i32,
        ..p
    };
    let too_small = GenError::TooSmall {
        width_m,
        height_m,
        resolution_m,
    };
    if !(width_m >= MIN_SIDE_M && height_m >= MIN_SIDE_M) {
        return Err(too_small);
    }
    let (w, h) = ((width_m / res).round(), (height_m / res).round());
    // Each side is checked too, so that neither can overflow an `i32` even if the other is 0.
    if w * h > MAX_CELLS as f64 || w.max(h) > MAX_CELLS as f64 {
        return Err(GenError::TooLarge {
            width: w as u64,
            height: h as u64,
        });
    }
    let (w, h) = (w as i32, h as i32);
    if w - 2 * p.wall < p.door || h - 2 * p.wall < p.door {
        return Err(too_small);
    }
    Ok((p, w, h))
}

/// Builds the world of `kind` inside `interior` (all occupied on entry).
fn build(kind: GeneratedWorld, g: &mut Grid, rng: &mut ChaCha8Rng, p: &Params, interior: Rect) {
    match kind {
        GeneratedWorld::Unstructured => {
            fill(g, interior, Occ::Free);
            let cover = rng.gen_range(0.10..0.20);
            scatter(g, rng, p, interior, None, cover);
        }
        GeneratedWorld::Office => {
            office(g, rng, p, interior, None);
        }
        GeneratedWorld::Corridor => {
            office(g, rng, p, interior, Some(1));
        }
        GeneratedWorld::TwoCorridors => {
            office(g, rng, p, interior, Some(2));
        }
        GeneratedWorld::Empty => fill(g, interior, Occ::Free),
        GeneratedWorld::Random => {
            fill(g, interior, Occ::Free);
            scatter(g, rng, p, interior, None, RANDOM_COVER);
        }
        GeneratedWorld::Library => library::library(g, rng, p, interior),
        GeneratedWorld::Mixed => {
            fill(g, interior, Occ::Free);
            let house = building(g, rng, p, interior);
            let cover = rng.gen_range(0.06..0.12);
            scatter(g, rng, p, interior, house, cover);
        }
    }
}

/// Occupies the free cells outside the largest free component: the free cells are one region.
fn close_off_unreachable(g: &mut Grid) {
    let mask = crate::reachable::largest_free_mask(g);
    for (c, keep) in g.cells_mut().iter_mut().zip(mask) {
        if *c == Occ::Free && !keep {
            *c = Occ::Occupied;
        }
    }
}

/// The share of the floor the `random` kind covers with obstacles (Simmons et al. 2000, "15 %
/// random obstacles").
const RANDOM_COVER: f64 = 0.15;

/// Scatters rectangles, bars, discs and blobs over `region` (outside `avoid`) until about
/// `cover` of its free cells are occupied. Each obstacle's bounding box, grown by more than a
/// passage, must be free, so obstacles never touch each other, the walls or a building, and
/// never close a passage.
fn scatter(
    g: &mut Grid,
    rng: &mut ChaCha8Rng,
    p: &Params,
    region: Rect,
    avoid: Option<Rect>,
    cover: f64,
) {
    let free = (region.y0..region.y1)
        .map(|y| {
            (region.x0..region.x1)
                .filter(|&x| g.get(Cell::new(x, y)) == Occ::Free)
                .count()
        })
        .sum::<usize>();
    let target = (free as f64 * cover) as usize;
    let gap = p.passage + 1;
    let mut placed = 0;
    // Bounded (about one try per 25 free cells): a crowded map just gets fewer obstacles.
    for _ in 0..4000.max(free / 25) {
        if placed >= target {
            break;
        }
        let (cx, cy) = (
            between(rng, region.x0, region.x1 - 1),
            between(rng, region.y0, region.y1 - 1),
        );
        let shape = random_shape(rng, p, cx, cy);
        let Some(bbox) = bounding_box(&shape) else {
            continue;
        };
        let grown = bbox.grow(gap);
        let clear_of =
            |a: &Rect| grown.x1 <= a.x0 || a.x1 <= grown.x0 || grown.y1 <= a.y0 || a.y1 <= grown.y0;
        let outside_avoid = match &avoid {
            Some(a) => clear_of(a),
            None => true,
        };
        if outside_avoid && all_free(g, grown) {
            placed += shape.len();
            for c in shape {
                g.set(c, Occ::Occupied);
            }
        }
    }
}

fn random_shape(rng: &mut ChaCha8Rng, p: &Params, cx: i32, cy: i32) -> Vec<Cell> {
    let rect = |w: i32, h: i32| -> Vec<Cell> {
        (0..h)
            .flat_map(|y| (0..w).map(move |x| Cell::new(cx + x - w / 2, cy + y - h / 2)))
            .collect()
    };
    match rng.gen_range(0..4) {
        0 => rect(
            p.cells(rng.gen_range(0.3..2.5)),
            p.cells(rng.gen_range(0.3..2.5)),
        ),
        1 if rng.gen_bool(0.5) => rect(p.cells(rng.gen_range(1.5..5.0)), p.wall),
        1 => rect(p.wall, p.cells(rng.gen_range(1.5..5.0))),
        2 => disc(cx, cy, rng.gen_range(0.3..1.3) / p.res),
        _ => {
            // A blob: a few overlapping discs around the centre.
            let r = rng.gen_range(0.4..1.0) / p.res;
            let mut cells = disc(cx, cy, r);
            for _ in 0..rng.gen_range(1..4) {
                let (dx, dy) = (rng.gen_range(-r..r), rng.gen_range(-r..r));
                cells.extend(disc(
                    cx + dx as i32,
                    cy + dy as i32,
                    r * rng.gen_range(0.6..1.0),
                ));
            }
            cells.sort_unstable();
            cells.dedup();
            cells
        }
    }
}

/// The cells whose centres lie within `r` cells of cell `(cx, cy)`'s centre.
fn disc(cx: i32, cy: i32, r: f64) -> Vec<Cell> {
    let n = r.ceil() as i32;
    let mut cells = Vec::new();
    for dy in -n..=n {
        for dx in -n..=n {
            if f64::from(dx * dx + dy * dy) <= r * r {
                cells.push(Cell::new(cx + dx, cy + dy));
            }
        }
    }
    cells
}

fn bounding_box(cells: &[Cell]) -> Option<Rect> {
    let first = cells.first()?;
    let init = Rect::new(first.x, first.y, first.x + 1, first.y + 1);
    Some(cells.iter().fold(init, |r, c| {
        Rect::new(
            r.x0.min(c.x),
            r.y0.min(c.y),
            r.x1.max(c.x + 1),
            r.y1.max(c.y + 1),
        )
    }))
}

/// A band of rooms between two walls, with the corridor it opens onto above or below it.
struct Band {
    y0: i32,
    y1: i32,
    corridor_above: bool,
}

/// Lays out an office inside `area` (all occupied on entry): double-loaded corridors across the
/// whole width, joined by vertical spines, with rooms on both sides, each with a door onto its
/// corridor and sometimes a door to its neighbour. Returns the corridors. `corridors`: exactly
/// that many corridors, the rooms' depth fitted to the height (as deep as the area allows, at
/// least 2 m; fewer corridors when even that does not fit); `None`: as many as rooms 3–5 m deep
/// allow.
fn office(
    g: &mut Grid,
    rng: &mut ChaCha8Rng,
    p: &Params,
    area: Rect,
    corridors: Option<i32>,
) -> Vec<Rect> {
    let Some(plan) = floor_plan(rng, p, area, corridors) else {
        // Too low for rooms beside a corridor: the whole area is one hall.
        fill(g, area, Occ::Free);
        return vec![area];
    };
    for &c in &plan.corridors {
        fill(g, c, Occ::Free);
    }
    let spines = spines(g, rng, p, area, &plan);
    for band in &plan.bands {
        let mut x = area.x0;
        let crossed: Vec<&Rect> = spines
            .iter()
            .filter(|s| s.y0 <= band.y0 && band.y1 <= s.y1)
            .collect();
        let mut cuts: Vec<(i32, i32)> = crossed.iter().map(|s| (s.x0, s.x1)).collect();
        cuts.push((area.x1, area.x1));
        for (cut0, cut1) in cuts {
            rooms(g, rng, p, band, x, cut0);
            x = x.max(cut1);
        }
    }
    plan.corridors
}

/// Where an office's corridors and room bands lie, from the bottom of its area up.
struct FloorPlan {
    bands: Vec<Band>,
    corridors: Vec<Rect>,
    /// The corridors' width (across them), also the spines'.
    corridor_w: i32,
}

/// Draws and stacks the bands and corridors of [`office`]; `None`: `area` is too low for rooms.
fn floor_plan(
    rng: &mut ChaCha8Rng,
    p: &Params,
    area: Rect,
    corridors: Option<i32>,
) -> Option<FloorPlan> {
    let t = p.wall;
    let cw = p.cells(rng.gen_range(1.4..2.2)).max(p.door);
    let mut rd = between(rng, p.cells(3.0), p.cells(5.0));
    if let Some(n) = corridors.filter(|&n| n > 0) {
        // n units of two room bands and a corridor, with walls between: n·unit + (n − 1)·t.
        let unit = (area.h() - (n - 1) * t) / n;
        rd = ((unit - cw - 2 * t) / 2).max(p.cells(2.0));
    }
    let unit = 2 * rd + cw + 2 * t;
    let units = (area.h() + t) / (unit + t);
    let units = corridors.map_or(units, |n| units.min(n));
    let mut bands = Vec::new();
    let mut corridors = Vec::new();
    if units >= 1 {
        // The height left over is shared out among the room bands.
        let spare = area.h() - (units * unit + (units - 1) * t);
        let depth = |i: i32| rd + spare / (2 * units) + i32::from(i < spare % (2 * units));
        let mut y = area.y0;
        for u in 0..units {
            let (below, above) = (depth(2 * u), depth(2 * u + 1));
            bands.push(Band {
                y0: y,
                y1: y + below,
                corridor_above: true,
            });
            y += below + t;
            corridors.push(Rect::new(area.x0, y, area.x1, y + cw));
            y += cw + t;
            bands.push(Band {
                y0: y,
                y1: y + above,
                corridor_above: false,
            });
            y += above + t;
        }
    } else if area.h() >= cw + t + p.cells(2.0) {
        corridors.push(Rect::new(area.x0, area.y0, area.x1, area.y0 + cw));
        bands.push(Band {
            y0: area.y0 + cw + t,
            y1: area.y1,
            corridor_above: false,
        });
    } else {
        return None;
    }
    Some(FloorPlan {
        bands,
        corridors,
        corridor_w: cw,
    })
}

/// Opens the spines joining the corridors (two over 40 m wide), returned grown by a wall.
fn spines(
    g: &mut Grid,
    rng: &mut ChaCha8Rng,
    p: &Params,
    area: Rect,
    plan: &FloorPlan,
) -> Vec<Rect> {
    let (t, cw, corridors) = (p.wall, plan.corridor_w, &plan.corridors);
    let mut spines = Vec::new();
    if let (Some(first), Some(last)) = (corridors.first(), corridors.last()) {
        if corridors.len() > 1 {
            let count = if f64::from(area.w()) * p.res > 40.0 {
                2
            } else {
                1
            };
            let slot = area.w() / count;
            for s in 0..count {
                let x = between(rng, area.x0 + s * slot, area.x0 + (s + 1) * slot - cw);
                let spine = Rect::new(x, first.y0, (x + cw).min(area.x1), last.y1);
                fill(g, spine, Occ::Free);
                spines.push(spine.grow(t));
            }
        }
    }
    spines
}

/// Splits `[x0, x1)` of a band into rooms 3–6 m wide separated by walls.
fn rooms(g: &mut Grid, rng: &mut ChaCha8Rng, p: &Params, band: &Band, x0: i32, x1: i32) {
    let (t, min_w, max_w) = (p.wall, p.cells(3.0), p.cells(6.0));
    let mut x = x0;
    let mut previous: Option<Rect> = None;
    while x1 - x >= p.door {
        let mut w = between(rng, min_w, max_w);
        if x1 - x - w < min_w + t {
            w = x1 - x;
        }
        let room = Rect::new(x, band.y0, x + w, band.y1);
        fill(g, room, Occ::Free);
        let dx = between(rng, room.x0, room.x1 - p.door);
        let door_y = if band.corridor_above {
            room.y1
        } else {
            room.y0 - t
        };
        fill(g, Rect::new(dx, door_y, dx + p.door, door_y + t), Occ::Free);
        if let Some(prev) = previous.filter(|_| rng.gen_bool(0.25)) {
            let dy = between(rng, room.y0, room.y1 - p.door);
            fill(g, Rect::new(prev.x1, dy, room.x0, dy + p.door), Occ::Free);
        }
        previous = Some(room);
        x += w + t;
    }
}

/// Places a building (an office with an outer wall) in the middle part of `area`, with
/// entrances at the ends of its corridors, and returns its outline. Skipped (`None`) when the
/// area is too small for one.
fn building(g: &mut Grid, rng: &mut ChaCha8Rng, p: &Params, area: Rect) -> Option<Rect> {
    let t = p.wall;
    let bw = (f64::from(area.w()) * rng.gen_range(0.4..0.6)) as i32;
    let bh = (f64::from(area.h()) * rng.gen_range(0.4..0.6)) as i32;
    let margin = p.passage + 2 + t;
    if bw < p.cells(6.0)
        || bh < p.cells(6.0)
        || area.w() - bw < 2 * margin
        || area.h() - bh < 2 * margin
    {
        return None;
    }
    let x0 = between(rng, area.x0 + margin, area.x1 - margin - bw);
    let y0 = between(rng, area.y0 + margin, area.y1 - margin - bh);
    let outer = Rect::new(x0, y0, x0 + bw, y0 + bh);
    fill(g, outer, Occ::Occupied);
    let inner = outer.grow(-t);
    for c in office(g, rng, p, inner, None) {
        // An entrance as high as the corridor (at most 2.2 m) through each end wall.
        let eh = c.h().min(p.cells(2.2));
        let ey = c.y0 + (c.h() - eh) / 2;
        fill(g, Rect::new(outer.x0, ey, inner.x0, ey + eh), Occ::Free);
        if rng.gen_bool(0.7) {
            fill(g, Rect::new(inner.x1, ey, outer.x1, ey + eh), Occ::Free);
        }
    }
    Some(outer)
}

/// Morphological opening of the free space by a `k × k` square: a free cell stays free only if
/// some all-free `k × k` square contains it. Uses summed-area tables, linear in the grid size.
fn open_free(g: &mut Grid, k: i32) {
    let (w, h, k) = (g.width() as usize, g.height() as usize, k.max(1) as usize);
    let stride = w + 1;
    let mut sum = vec![0u32; stride * (h + 1)];
    for y in 0..h {
        for x in 0..w {
            let free = u32::from(g.cells()[y * w + x] == Occ::Free);
            sum[(y + 1) * stride + x + 1] =
                free + sum[y * stride + x + 1] + sum[(y + 1) * stride + x] - sum[y * stride + x];
        }
    }
    // Difference table of the squares that are all free, then its prefix sum = coverage.
    let mut cover = vec![0i32; stride * (h + 1)];
    for y in 0..(h + 1).saturating_sub(k) {
        for x in 0..(w + 1).saturating_sub(k) {
            let s = sum[(y + k) * stride + x + k] + sum[y * stride + x]
                - sum[y * stride + x + k]
                - sum[(y + k) * stride + x];
            if s as usize == k * k {
                cover[y * stride + x] += 1;
                cover[y * stride + x + k] -= 1;
                cover[(y + k) * stride + x] -= 1;
                cover[(y + k) * stride + x + k] += 1;
            }
        }
    }
    for y in 0..h {
        for x in 0..w {
            let i = y * stride + x;
            let left = if x > 0 { cover[i - 1] } else { 0 };
            let down = if y > 0 { cover[i - stride] } else { 0 };
            let diag = if x > 0 && y > 0 {
                cover[i - stride - 1]
            } else {
                0
            };
            cover[i] += left + down - diag;
            if cover[i] == 0 && g.cells()[y * w + x] == Occ::Free {
                g.cells_mut()[y * w + x] = Occ::Occupied;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reachable::largest_free_component;
    use proptest::prelude::*;

    const KINDS: [GeneratedWorld; 8] = GeneratedWorld::ALL;

    /// The guarantees of every generated map: closed, ternary-free of unknown, one free region.
    fn check_invariants(map: &TruthMap) -> Result<(), String> {
        let g = &map.grid;
        if (map.info.width, map.info.height) != (g.width(), g.height()) {
            return Err("info and grid disagree".into());
        }
        if g.count(Occ::Unknown) != 0 {
            return Err("unknown cells".into());
        }
        let (w, h) = (g.width() as i32, g.height() as i32);
        let border = (0..w)
            .flat_map(|x| [Cell::new(x, 0), Cell::new(x, h - 1)])
            .chain((0..h).flat_map(|y| [Cell::new(0, y), Cell::new(w - 1, y)]));
        if border.into_iter().any(|c| g.get(c) != Occ::Occupied) {
            return Err("open border".into());
        }
        let free = g.count(Occ::Free);
        if free == 0 || largest_free_component(g).len() != free {
            return Err(format!("free cells not one region ({free} free)"));
        }
        Ok(())
    }

    /// Naive check that every free cell lies in some all-free k × k square.
    fn passages_at_least(g: &Grid, k: i32) -> bool {
        let square_free = |x0: i32, y0: i32| {
            (y0..y0 + k).all(|y| (x0..x0 + k).all(|x| g.get(Cell::new(x, y)) == Occ::Free))
        };
        (0..g.len())
            .map(|i| g.cell_of(i))
            .filter(|&c| g.get(c) == Occ::Free)
            .all(|c| {
                (c.y - k + 1..=c.y).any(|y0| (c.x - k + 1..=c.x).any(|x0| square_free(x0, y0)))
            })
    }

    #[test]
    fn same_seed_same_map_other_seed_other_map() {
        for kind in KINDS {
            let a = generate(kind, 30.0, 20.0, 0.1, 42).expect("valid size");
            assert_eq!(
                Ok(&a),
                generate(kind, 30.0, 20.0, 0.1, 42).as_ref(),
                "{kind:?}"
            );
            if kind == GeneratedWorld::Empty {
                continue; // one room: nothing to draw
            }
            assert_ne!(
                a.grid,
                generate(kind, 30.0, 20.0, 0.1, 43)
                    .expect("valid size")
                    .grid,
                "{kind:?}"
            );
        }
    }

    #[test]
    fn fifty_seeds_of_each_kind_are_closed_and_connected() {
        for kind in KINDS {
            let mut fractions = Vec::new();
            for seed in 0..50 {
                let map = generate(kind, 40.0, 30.0, 0.1, seed).expect("valid size");
                assert_eq!(check_invariants(&map), Ok(()), "{kind:?} seed {seed}");
                fractions.push(map.grid.count(Occ::Free) as f64 / map.grid.len() as f64);
            }
            let (lo, hi) = fractions
                .iter()
                .fold((1.0f64, 0.0f64), |(lo, hi), &f| (lo.min(f), hi.max(f)));
            // One empty room is all floor (its own test checks it exactly).
            let hi_max = if kind == GeneratedWorld::Empty {
                1.0
            } else {
                0.95
            };
            assert!(
                lo > 0.45 && hi < hi_max,
                "{kind:?}: free fraction {lo:.3}..{hi:.3}"
            );
        }
    }

    #[test]
    fn passages_are_at_least_0_8_m_wide() {
        for kind in KINDS {
            for seed in 0..5 {
                let map = generate(kind, 24.0, 18.0, 0.2, seed).expect("valid size");
                assert!(passages_at_least(&map.grid, 4), "{kind:?} seed {seed}");
            }
        }
    }

    #[test]
    fn offices_mixed_maps_and_libraries_have_rooms_behind_doors() {
        // Doors are 1 m wide, rooms at least 3 m: opening the free space by a 1.2 m square closes
        // every door and leaves the rooms as separate regions.
        for kind in [
            GeneratedWorld::Office,
            GeneratedWorld::Mixed,
            GeneratedWorld::Library,
        ] {
            for seed in 0..5 {
                let mut g = generate(kind, 40.0, 30.0, 0.2, seed)
                    .expect("valid size")
                    .grid;
                open_free(&mut g, 6);
                let free = g.count(Occ::Free);
                assert!(
                    free > 0 && largest_free_component(&g).len() < free,
                    "{kind:?} seed {seed}"
                );
            }
        }
    }

    /// Simmons et al.'s simulation worlds: one corridor and two parallel corridors across a
    /// 25 × 20 m office, an empty 20 × 20 m room, 15 % random obstacles.
    #[test]
    fn the_bids_worlds_have_their_corridors_and_cover() {
        // A corridor is a band of rows free across the whole width inside the outer wall.
        let corridor_rows = |g: &Grid| {
            let mut rows = 0;
            let mut inside = false;
            for y in 0..g.height() as i32 {
                let across = (1..g.width() as i32 - 1).all(|x| g.get(Cell::new(x, y)) == Occ::Free);
                if across && !inside {
                    rows += 1;
                }
                inside = across;
            }
            rows
        };
        for seed in 0..5 {
            let one = generate(GeneratedWorld::Corridor, 25.0, 20.0, 0.2, seed).expect("size");
            assert_eq!(corridor_rows(&one.grid), 1, "seed {seed}");
            let two = generate(GeneratedWorld::TwoCorridors, 25.0, 20.0, 0.2, seed).expect("size");
            assert_eq!(corridor_rows(&two.grid), 2, "seed {seed}");
            let empty = generate(GeneratedWorld::Empty, 20.0, 20.0, 0.2, seed).expect("size");
            let inner = (empty.grid.width() - 2) * (empty.grid.height() - 2);
            assert_eq!(empty.grid.count(Occ::Free), inner as usize, "one free room");
            let random = generate(GeneratedWorld::Random, 20.0, 20.0, 0.2, seed).expect("size");
            let cover = 1.0 - random.grid.count(Occ::Free) as f64 / f64::from(inner);
            assert!((0.10..0.20).contains(&cover), "seed {seed}: cover {cover}");
        }
    }

    /// de Hoog et al.'s library: a line across the stacks hall crosses many shelf rows, each as
    /// thick as a shelf (0.5 m, three cells at 0.2 m), which no other kind of world has.
    #[test]
    fn the_library_has_rows_of_shelves() {
        // Occupied runs exactly a shelf thick along a line of cells.
        let shelves = |line: Vec<Occ>| {
            line.split(|&o| o == Occ::Free)
                .filter(|run| run.len() == 3)
                .count()
        };
        for seed in 0..10 {
            let g = generate(GeneratedWorld::Library, 40.0, 30.0, 0.2, seed)
                .expect("valid size")
                .grid;
            let (w, h) = (g.width() as i32, g.height() as i32);
            let at = |x, y| g.get(Cell::new(x, y));
            let across = (0..h).map(|y| shelves((0..w).map(|x| at(x, y)).collect()));
            let down = (0..w).map(|x| shelves((0..h).map(|y| at(x, y)).collect()));
            let most = across.chain(down).max();
            assert!(most >= Some(6), "seed {seed}: at most {most:?} rows");
        }
    }

    #[test]
    fn open_free_removes_slivers_only() {
        let mut g = Grid::from_ascii(
            "#######\n\
             #..#..#\n\
             #..#..#\n\
             #.....#\n\
             #######\n",
        );
        open_free(&mut g, 2);
        assert_eq!(
            g.to_ascii(),
            "#######\n#..#..#\n#..#..#\n#..#..#\n#######\n"
        );
    }

    #[test]
    fn every_generated_world_generates_and_bad_sizes_are_errors() {
        // The one list of names (proto) and the generator agree: each world generates.
        for w in GeneratedWorld::ALL {
            let m = generate(w, 30.0, 20.0, 0.2, 1).unwrap_or_else(|e| panic!("{w:?}: {e}"));
            assert!(m.grid.count(Occ::Free) > 0, "{w:?}");
        }
        assert!(matches!(
            generate(GeneratedWorld::Office, 10.0, 10.0, 0.0, 0),
            Err(GenError::BadResolution { .. })
        ));
        assert!(matches!(
            generate(GeneratedWorld::Office, 10.0, 10.0, f64::NAN, 0),
            Err(GenError::BadResolution { .. })
        ));
        assert!(matches!(
            generate(GeneratedWorld::Office, 2.0, 10.0, 0.1, 0),
            Err(GenError::TooSmall { .. })
        ));
        assert!(matches!(
            generate(GeneratedWorld::Office, f64::NAN, 10.0, 0.1, 0),
            Err(GenError::TooSmall { .. })
        ));
        assert!(matches!(
            generate(GeneratedWorld::Office, 3.0, 3.0, 1.5, 0),
            Err(GenError::TooSmall { .. })
        ));
        assert!(matches!(
            generate(GeneratedWorld::Office, 1e6, 1e6, 0.1, 0),
            Err(GenError::TooLarge { .. })
        ));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn any_size_gives_a_valid_map(
            kind in prop::sample::select(KINDS.to_vec()),
            w in 3.0f64..45.0,
            h in 3.0f64..45.0,
            res in prop::sample::select(vec![0.1, 0.15, 0.2, 0.25, 0.5]),
            seed in any::<u64>(),
        ) {
            let map = generate(kind, w, h, res, seed).map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert_eq!(check_invariants(&map), Ok(()));
        }
    }
}
