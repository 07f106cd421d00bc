//! Ternary occupancy grids: the one grid type that crosses process boundaries.
//!
//! The truth map (world-server), every robot's self-explored grid G_s and planning grid G_p
//! (thesis §4.1, §5.2), and the grids robots report as telemetry are all [`Grid`]s of [`Occ`].
//! Cell `(x, y)` covers the square `[x, x+1) × [y, y+1)` in cell units; `y` grows upwards
//! (ROS convention), so row 0 is the *bottom* of a map image.
//!
//! Grids travel run-length encoded ([`Grid::to_rle`]): exploration grids are long runs of one
//! value, so RLE is small and needs no compression crate. Decoding is total: any byte string
//! either decodes into a grid or gives an [`RleError`].

use serde::{Deserialize, Serialize};

/// The state of one cell.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[repr(u8)]
pub enum Occ {
    #[default]
    Unknown = 0,
    Free = 1,
    Occupied = 2,
}

impl Occ {
    fn from_u8(v: u8) -> Option<Occ> {
        match v {
            0 => Some(Occ::Unknown),
            1 => Some(Occ::Free),
            2 => Some(Occ::Occupied),
            _ => None,
        }
    }
}

/// Integer grid index. Signed so that neighbours of border cells can be formed and rejected by
/// [`Grid::contains`] instead of wrapping.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Cell {
    pub x: i32,
    pub y: i32,
}

impl Cell {
    pub const fn new(x: i32, y: i32) -> Cell {
        Cell { x, y }
    }

    /// The four 4-neighbours: right, up, left, down.
    pub fn neighbours4(self) -> [Cell; 4] {
        let Cell { x, y } = self;
        [
            Cell::new(x + 1, y),
            Cell::new(x, y + 1),
            Cell::new(x - 1, y),
            Cell::new(x, y - 1),
        ]
    }
}

/// A rectangular ternary grid, row-major from the bottom row.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Grid {
    width: u32,
    height: u32,
    cells: Vec<Occ>,
}

/// Largest grid we accept from the network or a file (cells). 64 Mi cells = a 8192² map.
pub const MAX_CELLS: u64 = 64 * 1024 * 1024;

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum RleError {
    #[error("grid header truncated")]
    Truncated,
    #[error("grid of {width}x{height} cells is larger than the limit of {MAX_CELLS} cells")]
    TooLarge { width: u32, height: u32 },
    #[error("bad cell value {0} in run (allowed 0=unknown, 1=free, 2=occupied)")]
    BadValue(u8),
    #[error("runs cover {got} cells, grid has {want}")]
    WrongLength { got: u64, want: u64 },
    #[error("malformed varint")]
    BadVarint,
}

impl Grid {
    /// A grid of `width × height` cells, all `fill`.
    ///
    /// # Panics
    /// If the grid would exceed [`MAX_CELLS`]; callers validate sizes from outside first.
    pub fn new(width: u32, height: u32, fill: Occ) -> Grid {
        let n = u64::from(width) * u64::from(height);
        assert!(n <= MAX_CELLS, "grid {width}x{height} exceeds MAX_CELLS");
        Grid {
            width,
            height,
            cells: vec![fill; n as usize],
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    pub fn len(&self) -> usize {
        self.cells.len()
    }

    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    pub fn contains(&self, c: Cell) -> bool {
        c.x >= 0 && c.y >= 0 && (c.x as u32) < self.width && (c.y as u32) < self.height
    }

    /// Row-major index of an in-bounds cell.
    pub fn index(&self, c: Cell) -> Option<usize> {
        self.contains(c)
            .then(|| c.y as usize * self.width as usize + c.x as usize)
    }

    /// The cell of a row-major index.
    pub fn cell_of(&self, i: usize) -> Cell {
        Cell::new(
            (i % self.width as usize) as i32,
            (i / self.width as usize) as i32,
        )
    }

    /// The value at `c`; cells outside the grid read [`Occ::Unknown`].
    pub fn get(&self, c: Cell) -> Occ {
        self.index(c).map_or(Occ::Unknown, |i| self.cells[i])
    }

    /// Sets `c` (ignored outside the grid).
    pub fn set(&mut self, c: Cell, v: Occ) {
        if let Some(i) = self.index(c) {
            self.cells[i] = v;
        }
    }

    pub fn cells(&self) -> &[Occ] {
        &self.cells
    }

    pub fn cells_mut(&mut self) -> &mut [Occ] {
        &mut self.cells
    }

    pub fn count(&self, v: Occ) -> usize {
        self.cells.iter().filter(|&&c| c == v).count()
    }

    /// Parses an ASCII picture (`#` occupied, `.` free, `?` unknown), top line = top row.
    /// For tests and fixtures; panics on other characters or ragged lines.
    pub fn from_ascii(pic: &str) -> Grid {
        let lines: Vec<&str> = pic
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .collect();
        let height = lines.len() as u32;
        let width = lines.first().map_or(0, |l| l.chars().count()) as u32;
        let mut g = Grid::new(width, height, Occ::Unknown);
        for (row, line) in lines.iter().enumerate() {
            assert_eq!(line.chars().count() as u32, width, "ragged ASCII grid");
            let y = height as i32 - 1 - row as i32;
            for (x, ch) in line.chars().enumerate() {
                let v = match ch {
                    '#' => Occ::Occupied,
                    '.' => Occ::Free,
                    '?' => Occ::Unknown,
                    other => panic!("bad ASCII grid character {other:?}"),
                };
                g.set(Cell::new(x as i32, y), v);
            }
        }
        g
    }

    /// The inverse of [`Grid::from_ascii`].
    pub fn to_ascii(&self) -> String {
        let mut s = String::new();
        for y in (0..self.height as i32).rev() {
            for x in 0..self.width as i32 {
                s.push(match self.get(Cell::new(x, y)) {
                    Occ::Occupied => '#',
                    Occ::Free => '.',
                    Occ::Unknown => '?',
                });
            }
            s.push('\n');
        }
        s
    }

    /// Run-length encoding: varint width, varint height, then runs of (varint length<<2 | value).
    pub fn to_rle(&self) -> Vec<u8> {
        let mut out = Vec::new();
        put_varint(&mut out, u64::from(self.width));
        put_varint(&mut out, u64::from(self.height));
        let mut i = 0;
        while i < self.cells.len() {
            let v = self.cells[i];
            let mut j = i + 1;
            while j < self.cells.len() && self.cells[j] == v {
                j += 1;
            }
            put_varint(&mut out, ((j - i) as u64) << 2 | v as u64);
            i = j;
        }
        out
    }

    /// Decodes [`Grid::to_rle`]; total on arbitrary bytes.
    pub fn from_rle(bytes: &[u8]) -> Result<Grid, RleError> {
        let mut pos = 0;
        let width = get_varint(bytes, &mut pos)?;
        let height = get_varint(bytes, &mut pos)?;
        let (Ok(width), Ok(height)) = (u32::try_from(width), u32::try_from(height)) else {
            return Err(RleError::TooLarge {
                width: u32::MAX,
                height: u32::MAX,
            });
        };
        let want = u64::from(width) * u64::from(height);
        if want > MAX_CELLS {
            return Err(RleError::TooLarge { width, height });
        }
        let mut cells = Vec::with_capacity(want as usize);
        while pos < bytes.len() {
            let run = get_varint(bytes, &mut pos)?;
            let v = Occ::from_u8((run & 3) as u8).ok_or(RleError::BadValue((run & 3) as u8))?;
            let len = run >> 2;
            let got = cells.len() as u64 + len;
            if got > want {
                return Err(RleError::WrongLength { got, want });
            }
            cells.resize(got as usize, v);
        }
        if cells.len() as u64 != want {
            return Err(RleError::WrongLength {
                got: cells.len() as u64,
                want,
            });
        }
        Ok(Grid {
            width,
            height,
            cells,
        })
    }
}

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn get_varint(bytes: &[u8], pos: &mut usize) -> Result<u64, RleError> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let b = *bytes.get(*pos).ok_or(RleError::Truncated)?;
        *pos += 1;
        v |= u64::from(b & 0x7f) << shift;
        if b & 0x80 == 0 {
            return Ok(v);
        }
    }
    Err(RleError::BadVarint)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn ascii_round_trip_and_orientation() {
        let g = Grid::from_ascii("#..\n?.#\n");
        assert_eq!(
            g.get(Cell::new(0, 1)),
            Occ::Occupied,
            "top-left is the top row"
        );
        assert_eq!(g.get(Cell::new(0, 0)), Occ::Unknown);
        assert_eq!(g.get(Cell::new(2, 0)), Occ::Occupied);
        assert_eq!(g.to_ascii(), "#..\n?.#\n");
        assert_eq!(
            g.get(Cell::new(-1, 0)),
            Occ::Unknown,
            "outside reads unknown"
        );
    }

    #[test]
    fn rle_rejects_wrong_lengths() {
        let g = Grid::from_ascii("..#\n");
        let mut bytes = g.to_rle();
        bytes.pop();
        assert!(Grid::from_rle(&bytes).is_err());
        assert_eq!(Grid::from_rle(&[]), Err(RleError::Truncated));
    }

    fn arb_grid() -> impl Strategy<Value = Grid> {
        (0u32..20, 0u32..20).prop_flat_map(|(w, h)| {
            proptest::collection::vec(0u8..3, (w * h) as usize).prop_map(move |v| {
                let mut g = Grid::new(w, h, Occ::Unknown);
                for (c, b) in g.cells_mut().iter_mut().zip(v) {
                    *c = Occ::from_u8(b).unwrap_or_default();
                }
                g
            })
        })
    }

    proptest! {
        #[test]
        fn rle_round_trips(g in arb_grid()) {
            prop_assert_eq!(Grid::from_rle(&g.to_rle()), Ok(g));
        }

        #[test]
        fn rle_decoding_is_total(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
            let _ = Grid::from_rle(&bytes);
        }
    }
}
