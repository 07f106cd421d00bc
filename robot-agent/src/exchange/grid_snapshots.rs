//! The `grid-snapshots` baseline exchange (docs/design.md §4.8): the transitive log exchange of
//! [`crate::exchange::transitive`] carrying, per step, the cells of the self-explored grid G_s that the
//! step's scan changed (an incremental snapshot of the grid). Like raw scans it exists to
//! measure the polygon exchange against; unlike them it costs nothing to integrate on receipt.
//!
//! Receivers write every owner's patches, in log order, into one grid of what peers sensed;
//! the planning grid overlays G_s on it, so a peer never overrides a cell the robot sensed.

use proto::grid::{Cell, Grid, Occ};
use proto::msg::{GridPatch, Step};

use crate::exchange::transitive::LogExchange;

/// Every robot's patch log, exchanged transitively.
pub type GridPatchExchange = LogExchange<GridPatch>;

/// A patch that does not fit the receiver's grid.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum PatchError {
    #[error("patch is cut off inside a varint")]
    Truncated,
    #[error("patch names cell {0}, beyond the grid's {1} cells")]
    OutOfGrid(u64, usize),
    #[error("patch carries the unknown state value {0}")]
    BadState(u8),
}

/// The patch of step `step`: the states of `changed` cells (any order, duplicates allowed) in
/// `own`.
pub fn patch_of(step: Step, own: &Grid, changed: &[Cell]) -> GridPatch {
    let w = own.width() as i64;
    let mut idx: Vec<u64> = changed
        .iter()
        .filter(|c| c.x >= 0 && c.y >= 0 && i64::from(c.x) < w && c.y < own.height() as i32)
        .map(|c| (i64::from(c.y) * w + i64::from(c.x)) as u64)
        .collect();
    idx.sort_unstable();
    idx.dedup();
    let mut cells = Vec::new();
    let mut next = 0u64;
    for i in idx {
        let state = own.cells()[i as usize] as u64;
        put_varint(&mut cells, (i - next) << 2 | state);
        next = i + 1;
    }
    GridPatch { step, cells }
}

/// Writes a patch into `grid`; a patch that does not decode or does not fit changes nothing.
pub fn apply_patch(grid: &mut Grid, p: &GridPatch) -> Result<(), PatchError> {
    let mut writes = Vec::new();
    let (mut pos, mut next) = (0usize, 0u64);
    let len = grid.len();
    while pos < p.cells.len() {
        let v = get_varint(&p.cells, &mut pos).ok_or(PatchError::Truncated)?;
        let i = next.saturating_add(v >> 2);
        if i >= len as u64 {
            return Err(PatchError::OutOfGrid(i, len));
        }
        let state = match v & 3 {
            0 => Occ::Unknown,
            1 => Occ::Free,
            2 => Occ::Occupied,
            s => return Err(PatchError::BadState(s as u8)),
        };
        writes.push((i as usize, state));
        next = i + 1;
    }
    for (i, s) in writes {
        grid.set_index(i, s);
    }
    Ok(())
}

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn get_varint(bytes: &[u8], pos: &mut usize) -> Option<u64> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let b = *bytes.get(*pos)?;
        *pos += 1;
        v |= u64::from(b & 0x7f) << shift;
        if b & 0x80 == 0 {
            return Some(v);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn a_patch_carries_exactly_the_changed_cells() {
        let before = Grid::from_ascii("????\n????\n????\n");
        let after = Grid::from_ascii("??..\n?#..\n????\n");
        let changed: Vec<Cell> = (0..after.len())
            .filter(|&i| after.cells()[i] != before.cells()[i])
            .map(|i| Cell::new((i % 4) as i32, (i / 4) as i32))
            .collect();
        let p = patch_of(7, &after, &changed);
        assert_eq!(p.step, 7);
        assert_eq!(p.cells.len(), 5, "one byte per cell here");
        let mut g = before.clone();
        apply_patch(&mut g, &p).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(g, after);
    }

    #[test]
    fn patches_that_do_not_fit_change_nothing() {
        let mut g = Grid::new(3, 3, Occ::Unknown);
        let before = g.clone();
        let out = GridPatch {
            step: 0,
            cells: vec![1, 9 << 2 | 1],
        };
        assert_eq!(apply_patch(&mut g, &out), Err(PatchError::OutOfGrid(10, 9)));
        assert_eq!(
            apply_patch(
                &mut g,
                &GridPatch {
                    step: 0,
                    cells: vec![0x80]
                }
            ),
            Err(PatchError::Truncated)
        );
        assert_eq!(
            apply_patch(
                &mut g,
                &GridPatch {
                    step: 0,
                    cells: vec![3]
                }
            ),
            Err(PatchError::BadState(3))
        );
        assert_eq!(g, before);
    }

    proptest! {
        /// Any grid and any set of changed cells: applying the patch to the grid as it was
        /// yields the grid as it is; arbitrary bytes never panic.
        #[test]
        fn patches_round_trip(
            w in 1u32..20,
            h in 1u32..20,
            states in proptest::collection::vec(0u8..3, 400),
            picks in proptest::collection::vec((0i32..24, 0i32..24), 0..60),
            junk in proptest::collection::vec(any::<u8>(), 0..40),
        ) {
            let mut now = Grid::new(w, h, Occ::Unknown);
            let changed: Vec<Cell> = picks.iter().map(|&(x, y)| Cell::new(x, y)).collect();
            for (k, c) in changed.iter().enumerate() {
                if c.x < w as i32 && c.y < h as i32 {
                    let s = [Occ::Unknown, Occ::Free, Occ::Occupied][states[k] as usize];
                    now.cells_mut()[(c.y as u32 * w + c.x as u32) as usize] = s;
                }
            }
            let mut then = Grid::new(w, h, Occ::Unknown);
            apply_patch(&mut then, &patch_of(1, &now, &changed)).unwrap_or_else(|e| panic!("{e}"));
            prop_assert_eq!(then, now);
            let mut g = Grid::new(w, h, Occ::Unknown);
            let _ = apply_patch(&mut g, &GridPatch { step: 0, cells: junk });
        }
    }
}
