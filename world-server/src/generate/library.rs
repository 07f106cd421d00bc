//! The `library` world: a library floor, standing in for the Radish data set's
//! `vasche_library_floor1`, which de Hoog, Cameron & Visser (TAROS 2010) explored with a team
//! that keeps in touch by radio.
//!
//! The stacks hall takes the middle of the floor, about half of it. Rooms line the top and the
//! bottom edge of the floor, each with a door onto a corridor along the hall (as in
//! [`office`]). An entrance lobby with a desk joins the two corridors at the left, a third
//! corridor at the right closes the ring. The hall has its own wall with openings onto the
//! lobby and the corridors. Inside it, an aisle follows the wall and main aisles cut the floor
//! into blocks; each block holds parallel rows of 0.5 m shelves with aisles 1.2–1.6 m wide
//! between them, some rows shortened at an end or broken by a gap. Every row ends on an aisle
//! wider than a passage, so every shelf aisle is reachable. A floor too small for this ring
//! (about 20 × 16 m) is an [`office`] instead.

use proto::grid::{Grid, Occ};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::{between, fill, office, rooms, Band, Params, Rect};

/// Thickness of a shelf row.
const SHELF_M: f64 = 0.5;
/// Narrowest and widest aisle between two rows.
const AISLE_M: std::ops::Range<f64> = 1.2..1.6;

/// Lays out a library inside `area` (all occupied on entry).
pub(super) fn library(g: &mut Grid, rng: &mut ChaCha8Rng, p: &Params, area: Rect) {
    let t = p.wall;
    let cw = p.cells(rng.gen_range(1.6..2.2)).max(p.door);
    let (below, above) = (
        between(rng, p.cells(3.0), p.cells(4.5)),
        between(rng, p.cells(3.0), p.cells(4.5)),
    );
    let lobby = between(rng, p.cells(3.5), p.cells(5.0));
    // Bottom to top: rooms, wall, corridor, wall, hall, wall, corridor, wall, rooms; left to
    // right: lobby, wall, hall, wall, corridor.
    let hall = Rect::new(
        area.x0 + lobby + t,
        area.y0 + below + cw + 2 * t,
        area.x1 - cw - t,
        area.y1 - above - cw - 2 * t,
    );
    if hall.h() < p.cells(6.0) || hall.w() < p.cells(8.0) {
        office(g, rng, p, area, None);
        return;
    }
    let bottom = Rect::new(area.x0, hall.y0 - t - cw, area.x1, hall.y0 - t);
    let top = Rect::new(area.x0, hall.y1 + t, area.x1, hall.y1 + t + cw);
    for r in [
        bottom,
        top,
        Rect::new(area.x0, bottom.y0, area.x0 + lobby, top.y1),
        Rect::new(hall.x1 + t, bottom.y0, area.x1, top.y1),
        hall,
    ] {
        fill(g, r, Occ::Free);
    }
    let bands = [
        Band {
            y0: area.y0,
            y1: bottom.y0 - t,
            corridor_above: true,
        },
        Band {
            y0: top.y1 + t,
            y1: area.y1,
            corridor_above: false,
        },
    ];
    for band in &bands {
        rooms(g, rng, p, band, area.x0, area.x1);
    }
    desk(
        g,
        rng,
        p,
        Rect::new(area.x0, bottom.y0, area.x0 + lobby, top.y1),
    );
    stacks(g, rng, p, hall);
}

/// A counter across the middle of the lobby, when the lobby leaves more than a passage on
/// each side of it.
fn desk(g: &mut Grid, rng: &mut ChaCha8Rng, p: &Params, lobby: Rect) {
    let (dw, dh) = (p.cells(0.8), p.cells(rng.gen_range(2.0..3.0)));
    let gap = (lobby.w() - dw) / 2;
    if gap > p.passage && lobby.h() > dh + 2 * (p.passage + 1) {
        let y0 = lobby.y0 + (lobby.h() - dh) / 2;
        let x0 = lobby.x0 + gap;
        fill(g, Rect::new(x0, y0, x0 + dw, y0 + dh), Occ::Occupied);
    }
}

/// Fills the hall with blocks of shelves between aisles and opens its wall (a ring `p.wall`
/// thick around `hall`) where the main aisles meet it: always onto the lobby, sometimes onto
/// the corridors.
fn stacks(g: &mut Grid, rng: &mut ChaCha8Rng, p: &Params, hall: Rect) {
    let t = p.wall;
    let edge = p.cells(rng.gen_range(1.4..1.8)).max(p.passage + 1);
    let main = p.cells(rng.gen_range(1.8..2.4)).max(p.door);
    let inner = hall.grow(-edge);
    let block_w = between(rng, p.cells(7.0), p.cells(11.0));
    let block_h = between(rng, p.cells(5.0), p.cells(8.0));
    let cols = spans(inner.x0, inner.x1, block_w, main);
    let rows = spans(inner.y0, inner.y1, block_h, main);
    let along_y = rng.gen_bool(0.5);
    for &(x0, x1) in &cols {
        for &(y0, y1) in &rows {
            shelves(g, rng, p, Rect::new(x0, y0, x1, y1), along_y);
        }
    }
    let across = aisles(&rows, (hall.y0, hall.y1), main);
    let down = aisles(&cols, (hall.x0, hall.x1), main);
    for &(y0, y1) in &across {
        fill(g, Rect::new(hall.x0 - t, y0, hall.x0, y1), Occ::Free);
        if rng.gen_bool(0.5) {
            fill(g, Rect::new(hall.x1, y0, hall.x1 + t, y1), Occ::Free);
        }
    }
    for &(x0, x1) in &down {
        if rng.gen_bool(0.5) {
            fill(g, Rect::new(x0, hall.y0 - t, x1, hall.y0), Occ::Free);
        }
        if rng.gen_bool(0.5) {
            fill(g, Rect::new(x0, hall.y1, x1, hall.y1 + t), Occ::Free);
        }
    }
}

/// Splits `[lo, hi)` into as many spans about `target` long as fit with `gap` between them
/// (at least one).
fn spans(lo: i32, hi: i32, target: i32, gap: i32) -> Vec<(i32, i32)> {
    let n = ((hi - lo + gap) / (target + gap)).max(1);
    let len = (hi - lo - (n - 1) * gap) / n;
    (0..n)
        .map(|i| {
            let a = lo + i * (len + gap);
            (a, if i == n - 1 { hi } else { a + len })
        })
        .collect()
}

/// The main aisles between consecutive `blocks`, or one `width` wide across the middle of
/// `whole` when there is a single block.
fn aisles(blocks: &[(i32, i32)], whole: (i32, i32), width: i32) -> Vec<(i32, i32)> {
    match blocks {
        [] | [_] => {
            let mid = (whole.0 + whole.1 - width) / 2;
            vec![(mid, mid + width)]
        }
        _ => blocks.windows(2).map(|w| (w[0].1, w[1].0)).collect(),
    }
}

/// Rows of shelves across `block` (running along y when `along_y`), centred in it, each with an
/// aisle of its own width before the next. Rows reach the block's ends unless trimmed.
fn shelves(g: &mut Grid, rng: &mut ChaCha8Rng, p: &Params, block: Rect, along_y: bool) {
    // (a, b): across the rows, along them.
    let (a0, a1, b0, b1) = if along_y {
        (block.x0, block.x1, block.y0, block.y1)
    } else {
        (block.y0, block.y1, block.x0, block.x1)
    };
    let rect = |a0: i32, a1: i32, b0: i32, b1: i32| {
        if along_y {
            Rect::new(a0, b0, a1, b1)
        } else {
            Rect::new(b0, a0, b1, a1)
        }
    };
    let st = p.cells(SHELF_M);
    if b1 - b0 < p.cells(2.0) {
        return;
    }
    let mut starts = Vec::new();
    let mut a = a0;
    while a + st <= a1 {
        starts.push(a);
        a += st + p.cells(rng.gen_range(AISLE_M)).max(p.passage + 1);
    }
    let shift = starts.last().map_or(0, |&last| (a1 - last - st) / 2);
    // Only rows of 4 m or more lose up to a metre at an end.
    let trim = p.cells(1.0);
    let trimmed = |rng: &mut ChaCha8Rng| {
        if b1 - b0 >= 4 * trim && rng.gen_bool(0.2) {
            between(rng, 1, trim)
        } else {
            0
        }
    };
    for a in starts {
        let a = a + shift;
        let (lo, hi) = (b0 + trimmed(rng), b1 - trimmed(rng));
        let gap = p.cells(rng.gen_range(AISLE_M)).max(p.passage + 1);
        let end = p.cells(1.5);
        if hi - lo >= 2 * end + gap && rng.gen_bool(0.2) {
            let cut = between(rng, lo + end, hi - end - gap);
            fill(g, rect(a, a + st, lo, cut), Occ::Occupied);
            fill(g, rect(a, a + st, cut + gap, hi), Occ::Occupied);
        } else {
            fill(g, rect(a, a + st, lo, hi), Occ::Occupied);
        }
    }
}
