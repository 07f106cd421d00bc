//! The map the team has to learn: the truth's reachable free cells and the walls that bound
//! them, everything else unknown. The launcher writes it as `grids/truth_reachable.pgm`;
//! `scripts/information_floor.py` compresses it (lzma) to the information floor a run's radio
//! bytes are compared with (docs/run-directory.md).

use proto::grid::{Cell, Grid, Occ};

/// From the truth and its reachable free cells (`Free` in `reachable`): those cells free, every
/// truth-occupied cell next to one of them (8-neighbourhood) occupied, the rest unknown.
pub fn reachable_map(truth: &Grid, reachable: &Grid) -> Grid {
    let (w, h) = (truth.width(), truth.height());
    let mut out = Grid::new(w, h, Occ::Unknown);
    for y in 0..h as i32 {
        for x in 0..w as i32 {
            let c = Cell::new(x, y);
            if reachable.get(c) == Occ::Free {
                out.set(c, Occ::Free);
                continue;
            }
            if truth.get(c) != Occ::Occupied {
                continue;
            }
            let bounds = (-1..=1)
                .flat_map(|dy| (-1..=1).map(move |dx| Cell::new(x + dx, y + dy)))
                .any(|n| reachable.get(n) == Occ::Free);
            if bounds {
                out.set(c, Occ::Occupied);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reachable_room_and_its_walls_are_known_the_rest_is_not() {
        // A 6×3 strip: a wall column at x = 3 splits a reachable room (x < 3) from one that
        // is not; the outer row is wall.
        let mut truth = Grid::new(6, 3, Occ::Free);
        for x in 0..6 {
            truth.set(Cell::new(x, 2), Occ::Occupied);
        }
        for y in 0..3 {
            truth.set(Cell::new(3, y), Occ::Occupied);
        }
        let seen = truth.reachable(&[Cell::new(0, 0)]);
        let mut reachable = Grid::new(6, 3, Occ::Unknown);
        for y in 0..3 {
            for x in 0..6 {
                let c = Cell::new(x, y);
                if truth.index(c).is_some_and(|i| seen[i]) {
                    reachable.set(c, Occ::Free);
                }
            }
        }
        let map = reachable_map(&truth, &reachable);
        assert_eq!(map.get(Cell::new(1, 1)), Occ::Free);
        assert_eq!(
            map.get(Cell::new(3, 1)),
            Occ::Occupied,
            "the wall the room sees"
        );
        assert_eq!(map.get(Cell::new(1, 2)), Occ::Occupied);
        assert_eq!(
            map.get(Cell::new(4, 1)),
            Occ::Unknown,
            "the room nobody reaches"
        );
        assert_eq!(
            map.get(Cell::new(5, 2)),
            Occ::Unknown,
            "a wall only that room sees"
        );
    }
}
