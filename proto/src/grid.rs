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

    /// The cell's centre in cell units (cell `(x, y)` covers `[x, x+1) × [y, y+1)`).
    pub fn centre(self) -> (f64, f64) {
        (f64::from(self.x) + 0.5, f64::from(self.y) + 0.5)
    }

    /// The Euclidean distance between two cells' centres, in cells.
    pub fn dist(self, other: Cell) -> f64 {
        f64::from(self.x - other.x).hypot(f64::from(self.y - other.y))
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

/// A rectangle of cells, from `min` to `max` inclusive (`min.x <= max.x`, `min.y <= max.y`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Rect {
    pub min: Cell,
    pub max: Cell,
}

impl Rect {
    /// The rectangle of one cell.
    pub const fn cell(c: Cell) -> Rect {
        Rect { min: c, max: c }
    }

    /// The smallest rectangle holding both.
    pub fn union(self, o: Rect) -> Rect {
        Rect {
            min: Cell::new(self.min.x.min(o.min.x), self.min.y.min(o.min.y)),
            max: Cell::new(self.max.x.max(o.max.x), self.max.y.max(o.max.y)),
        }
    }

    /// [`Rect::union`] of optional rectangles (`None`: no cell).
    pub fn union_of(a: Option<Rect>, b: Option<Rect>) -> Option<Rect> {
        match (a, b) {
            (Some(a), Some(b)) => Some(a.union(b)),
            (a, None) => a,
            (None, b) => b,
        }
    }

    /// The smallest rectangle holding every cell of `cells` (`None`: none).
    pub fn around(cells: impl IntoIterator<Item = Cell>) -> Option<Rect> {
        let mut cells = cells.into_iter();
        let first = cells.next()?;
        Some(cells.fold(Rect::cell(first), |r, c| Rect {
            min: Cell::new(r.min.x.min(c.x), r.min.y.min(c.y)),
            max: Cell::new(r.max.x.max(c.x), r.max.y.max(c.y)),
        }))
    }

    /// The cells the two share (`None`: none).
    pub fn intersection(self, o: Rect) -> Option<Rect> {
        let r = Rect {
            min: Cell::new(self.min.x.max(o.min.x), self.min.y.max(o.min.y)),
            max: Cell::new(self.max.x.min(o.max.x), self.max.y.min(o.max.y)),
        };
        (r.min.x <= r.max.x && r.min.y <= r.max.y).then_some(r)
    }

    /// Whether the two share a cell.
    pub fn intersects(self, o: Rect) -> bool {
        self.min.x <= o.max.x
            && o.min.x <= self.max.x
            && self.min.y <= o.max.y
            && o.min.y <= self.max.y
    }

    /// `by` cells more on every side.
    pub fn grown(self, by: i32) -> Rect {
        Rect {
            min: Cell::new(self.min.x - by, self.min.y - by),
            max: Cell::new(self.max.x + by, self.max.y + by),
        }
    }

    /// The part inside a `width × height` grid (`None`: nothing of it).
    pub fn within(self, width: u32, height: u32) -> Option<Rect> {
        let (w, h) = (i32::try_from(width).ok()?, i32::try_from(height).ok()?);
        let r = Rect {
            min: Cell::new(self.min.x.max(0), self.min.y.max(0)),
            max: Cell::new(self.max.x.min(w - 1), self.max.y.min(h - 1)),
        };
        (r.min.x <= r.max.x && r.min.y <= r.max.y).then_some(r)
    }

    pub fn width(&self) -> u32 {
        (self.max.x - self.min.x + 1) as u32
    }

    pub fn height(&self) -> u32 {
        (self.max.y - self.min.y + 1) as u32
    }

    /// Cells in it.
    pub fn area(&self) -> usize {
        self.width() as usize * self.height() as usize
    }

    pub fn contains(&self, c: Cell) -> bool {
        (self.min.x..=self.max.x).contains(&c.x) && (self.min.y..=self.max.y).contains(&c.y)
    }

    /// Its cells in row-major order (bottom row first), as the grid stores them.
    pub fn cells(self) -> impl Iterator<Item = Cell> {
        (self.min.y..=self.max.y)
            .flat_map(move |y| (self.min.x..=self.max.x).map(move |x| Cell::new(x, y)))
    }
}

/// A rectangular ternary grid, row-major from the bottom row.
///
/// It knows a rectangle outside which every cell is unknown ([`Grid::known_bounds`]), so that
/// the work on a grid that is mostly unexplored — counting, encoding, searching it — costs in
/// proportion to the explored part, not to the map's area.
///
/// **Invariant:** every cell that is not [`Occ::Unknown`] lies inside `known` (`None`: every
/// cell is unknown). `known` may be larger than needed: it grows with what is set and does not
/// shrink when a cell becomes unknown again.
#[derive(Clone, Debug)]
pub struct Grid {
    width: u32,
    height: u32,
    cells: Vec<Occ>,
    known: Option<Rect>,
}

/// Grids are equal when their cells are (their known bounds may differ).
impl PartialEq for Grid {
    fn eq(&self, o: &Grid) -> bool {
        self.width == o.width && self.height == o.height && self.cells == o.cells
    }
}

impl Eq for Grid {}

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
        let mut g = Grid {
            width,
            height,
            cells: vec![fill; n as usize],
            known: None,
        };
        if fill != Occ::Unknown {
            g.known = g.whole();
        }
        g
    }

    /// The rectangle of the whole grid (`None`: an empty grid).
    pub fn whole(&self) -> Option<Rect> {
        Rect {
            min: Cell::new(0, 0),
            max: Cell::new(self.width as i32 - 1, self.height as i32 - 1),
        }
        .within(self.width, self.height)
    }

    /// A rectangle outside which every cell is unknown (`None`: every cell is).
    pub fn known_bounds(&self) -> Option<Rect> {
        self.known
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

    #[inline]
    pub fn contains(&self, c: Cell) -> bool {
        c.x >= 0 && c.y >= 0 && (c.x as u32) < self.width && (c.y as u32) < self.height
    }

    /// Row-major index of an in-bounds cell.
    #[inline]
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
    #[inline]
    pub fn get(&self, c: Cell) -> Occ {
        self.index(c).map_or(Occ::Unknown, |i| self.cells[i])
    }

    /// Whether `c` is a frontier cell (Yamauchi 1997): free, with a 4-neighbour inside the grid
    /// that is unknown. Beyond the grid's edge there is nothing to explore, so the edge is no
    /// frontier. Whether a robot can reach the cell is the planner's question
    /// (`robot_agent::nav::plan::is_frontier`); this is the one test of the cell itself, for the
    /// planner and the viewer alike.
    pub fn is_frontier(&self, c: Cell) -> bool {
        frontier(c, |n| self.contains(n), |n| self.get(n))
    }

    /// Which cells a robot standing on any of `seeds` can reach (row-major, one flag per cell):
    /// the free cells 4-connected to a free seed (seeds that are not free reach nothing).
    ///
    /// The one rule of reachability. Robots move along straight segments and the world refuses a
    /// move that sweeps a cell that is not free ([`crate::traverse::swept`]), so no move
    /// squeezes through the corner between two blocked cells: 4-connectivity. The evaluator's
    /// reachable area is this rule on the truth from the spawn cells; a robot's planner
    /// (8-connected, a diagonal step only between two free orthogonal neighbours) reaches
    /// exactly this set on its planning grid, which its property tests check.
    pub fn reachable(&self, seeds: &[Cell]) -> Vec<bool> {
        let mut seen = vec![false; self.len()];
        self.reach_into(seeds, &mut seen);
        seen
    }

    /// [`Grid::reachable`] into `seen` (one flag per cell), flooding only from cells not yet
    /// marked: marks what the seeds reach and returns how many cells it newly marked. Floods
    /// from unmarked cells one after another label the free regions of a grid.
    ///
    /// # Panics
    /// If `seen` has not [`Grid::len`] flags.
    pub fn reach_into(&self, seeds: &[Cell], seen: &mut [bool]) -> usize {
        assert_eq!(seen.len(), self.len(), "one flag per cell");
        let mut stack = Vec::new();
        let mut visit = |c: Cell, stack: &mut Vec<Cell>| {
            if let Some(i) = self
                .index(c)
                .filter(|&i| self.cells[i] == Occ::Free && !seen[i])
            {
                seen[i] = true;
                stack.push(c);
            }
        };
        for &s in seeds {
            visit(s, &mut stack);
        }
        let mut marked = 0;
        while let Some(c) = stack.pop() {
            marked += 1;
            for n in c.neighbours4() {
                visit(n, &mut stack);
            }
        }
        marked
    }

    /// Sets `c` (ignored outside the grid).
    pub fn set(&mut self, c: Cell, v: Occ) {
        if let Some(i) = self.index(c) {
            self.set_index(i, v);
        }
    }

    /// Sets the cell of row-major index `i`.
    ///
    /// # Panics
    /// If `i` is not below [`Grid::len`].
    pub fn set_index(&mut self, i: usize, v: Occ) {
        self.cells[i] = v;
        if v != Occ::Unknown {
            let c = self.cell_of(i);
            self.known = Rect::union_of(self.known, Some(Rect::cell(c)));
        }
    }

    pub fn cells(&self) -> &[Occ] {
        &self.cells
    }

    /// Every cell, to write at will: the grid counts all of them as possibly known afterwards
    /// (prefer [`Grid::set`] where few cells change).
    pub fn cells_mut(&mut self) -> &mut [Occ] {
        self.known = self.whole();
        &mut self.cells
    }

    /// The cells of row `y` from column `x0` to `x1` inclusive.
    ///
    /// # Panics
    /// If they are not all inside the grid.
    pub fn row(&self, y: i32, x0: i32, x1: i32) -> &[Occ] {
        let w = self.width as usize;
        let start = y as usize * w;
        &self.cells[start + x0 as usize..=start + x1 as usize]
    }

    /// [`Grid::row`] to write: the grid counts all of those cells as possibly known.
    ///
    /// # Panics
    /// If they are not all inside the grid.
    pub fn row_mut(&mut self, y: i32, x0: i32, x1: i32) -> &mut [Occ] {
        let r = Rect {
            min: Cell::new(x0, y),
            max: Cell::new(x1, y),
        };
        self.known = Rect::union_of(self.known, Some(r));
        let w = self.width as usize;
        let start = y as usize * w;
        &mut self.cells[start + x0 as usize..=start + x1 as usize]
    }

    /// How many cells are `v` (in proportion to [`Grid::known_bounds`]' area).
    pub fn count(&self, v: Occ) -> usize {
        let Some(r) = self.known else {
            return if v == Occ::Unknown { self.len() } else { 0 };
        };
        let inside: usize = (r.min.y..=r.max.y)
            .map(|y| {
                // Summed without a branch, so that it runs many cells at a time.
                self.row(y, r.min.x, r.max.x)
                    .iter()
                    .map(|&c| usize::from(c as u8 == v as u8))
                    .sum::<usize>()
            })
            .sum();
        if v == Occ::Unknown {
            inside + (self.len() - r.area())
        } else {
            inside
        }
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

    /// Run-length encoding: varint width, varint height, then maximal runs of
    /// (varint length<<2 | value). Reads only the cells inside [`Grid::known_bounds`]: the rest
    /// are unknown.
    pub fn to_rle(&self) -> Vec<u8> {
        let mut runs = Runs {
            out: Vec::new(),
            value: Occ::Unknown,
            len: 0,
        };
        put_varint(&mut runs.out, u64::from(self.width));
        put_varint(&mut runs.out, u64::from(self.height));
        let w = u64::from(self.width);
        match self.known {
            None => runs.push(Occ::Unknown, self.cells.len() as u64),
            Some(r) => {
                runs.push(Occ::Unknown, r.min.y as u64 * w);
                for y in r.min.y..=r.max.y {
                    runs.push(Occ::Unknown, r.min.x as u64);
                    for &v in self.row(y, r.min.x, r.max.x) {
                        runs.push(v, 1);
                    }
                    runs.push(Occ::Unknown, w - 1 - r.max.x as u64);
                }
                runs.push(
                    Occ::Unknown,
                    (u64::from(self.height) - 1 - r.max.y as u64) * w,
                );
            }
        }
        runs.finish()
    }

    /// Decodes [`Grid::to_rle`]; total on arbitrary bytes.
    pub fn from_rle(bytes: &[u8]) -> Result<Grid, RleError> {
        KnownPart::from_rle(bytes).map(|p| p.to_grid())
    }
}

/// The frontier test of [`Grid::is_frontier`] over any reading of a grid: `c` is free and a
/// 4-neighbour inside the grid is unknown.
fn frontier(c: Cell, inside: impl Fn(Cell) -> bool, get: impl Fn(Cell) -> Occ) -> bool {
    get(c) == Occ::Free
        && c.neighbours4()
            .iter()
            .any(|&n| inside(n) && get(n) == Occ::Unknown)
}

/// The known part of a grid as its run-length encoding gives it, decoded in proportion to that
/// part (and to the number of runs), not to the grid's area: the grid's size, the rectangle
/// outside which every cell is unknown, and the cells inside it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct KnownPart {
    width: u32,
    height: u32,
    rect: Option<Rect>,
    /// The cells of `rect`, row-major from its bottom row.
    cells: Vec<Occ>,
}

impl KnownPart {
    /// Decodes [`Grid::to_rle`]; total on arbitrary bytes (the errors of [`Grid::from_rle`]).
    pub fn from_rle(bytes: &[u8]) -> Result<KnownPart, RleError> {
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
        // First the runs that are not unknown, and the rectangle they span.
        let mut runs: Vec<(u64, u64, Occ)> = Vec::new();
        let mut rect = None;
        let mut got = 0u64;
        while pos < bytes.len() {
            let run = get_varint(bytes, &mut pos)?;
            let v = Occ::from_u8((run & 3) as u8).ok_or(RleError::BadValue((run & 3) as u8))?;
            let len = run >> 2;
            let first = got;
            got = got.saturating_add(len);
            if got > want {
                return Err(RleError::WrongLength { got, want });
            }
            if v != Occ::Unknown && len > 0 {
                // The rows the run spans; all their columns if it spans more than one.
                let w = u64::from(width);
                let last = got - 1;
                let (y0, y1) = ((first / w) as i32, (last / w) as i32);
                let (x0, x1) = if y0 == y1 {
                    ((first % w) as i32, (last % w) as i32)
                } else {
                    (0, width as i32 - 1)
                };
                let r = Rect {
                    min: Cell::new(x0, y0),
                    max: Cell::new(x1, y1),
                };
                rect = Rect::union_of(rect, Some(r));
                runs.push((first, len, v));
            }
        }
        if got != want {
            return Err(RleError::WrongLength { got, want });
        }
        // Then their cells, inside the rectangle.
        let mut part = KnownPart {
            width,
            height,
            rect,
            cells: vec![Occ::Unknown; rect.map_or(0, |r| r.area())],
        };
        if let Some(r) = rect {
            let (w, rw) = (u64::from(width), r.width() as usize);
            for (first, len, v) in runs {
                // Row by row: the run's cells of each row are one slice of the part.
                let mut i = first;
                while i < first + len {
                    let (x, y) = ((i % w) as i32, (i / w) as i32);
                    let n = (first + len - i).min(w - x as u64) as usize;
                    let k = (y - r.min.y) as usize * rw + (x - r.min.x) as usize;
                    part.cells[k..k + n].fill(v);
                    i += n as u64;
                }
            }
        }
        Ok(part)
    }

    /// The known part of `g` (a copy of the cells inside its known bounds).
    pub fn of(g: &Grid) -> KnownPart {
        let rect = g.known_bounds();
        let cells = rect
            .into_iter()
            .flat_map(|r| (r.min.y..=r.max.y).flat_map(move |y| g.row(y, r.min.x, r.max.x)))
            .copied()
            .collect();
        KnownPart {
            width: g.width,
            height: g.height,
            rect,
            cells,
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// The rectangle outside which every cell is unknown (`None`: every cell is).
    pub fn rect(&self) -> Option<Rect> {
        self.rect
    }

    /// The value at `c`; unknown outside the rectangle and outside the grid.
    pub fn get(&self, c: Cell) -> Occ {
        match self.rect {
            Some(r) if r.contains(c) => {
                self.cells[(c.y - r.min.y) as usize * r.width() as usize + (c.x - r.min.x) as usize]
            }
            _ => Occ::Unknown,
        }
    }

    /// [`Grid::is_frontier`] of the decoded grid, without decoding it.
    pub fn is_frontier(&self, c: Cell) -> bool {
        let inside = |n: Cell| {
            n.x >= 0 && n.y >= 0 && (n.x as u32) < self.width && (n.y as u32) < self.height
        };
        frontier(c, inside, |n| self.get(n))
    }

    /// Row `y` of the rectangle, from its left column (empty outside it).
    pub fn row(&self, y: i32) -> &[Occ] {
        match self.rect {
            Some(r) if (r.min.y..=r.max.y).contains(&y) => {
                let w = r.width() as usize;
                let k = (y - r.min.y) as usize * w;
                &self.cells[k..k + w]
            }
            _ => &[],
        }
    }

    /// The cells of the rectangle with their values, row-major from its bottom row.
    pub fn cells(&self) -> impl Iterator<Item = (Cell, Occ)> + '_ {
        self.rect
            .into_iter()
            .flat_map(Rect::cells)
            .zip(self.cells.iter().copied())
    }

    /// The whole grid.
    pub fn to_grid(&self) -> Grid {
        let mut g = Grid::new(self.width, self.height, Occ::Unknown);
        if let Some(r) = self.rect {
            for y in r.min.y..=r.max.y {
                g.row_mut(y, r.min.x, r.max.x).copy_from_slice(self.row(y));
            }
        }
        g
    }
}

/// Maximal runs of equal cells as [`Grid::to_rle`] writes them.
struct Runs {
    out: Vec<u8>,
    value: Occ,
    len: u64,
}

impl Runs {
    fn push(&mut self, v: Occ, n: u64) {
        if n == 0 {
            return;
        }
        if v != self.value && self.len > 0 {
            put_varint(&mut self.out, self.len << 2 | self.value as u64);
            self.len = 0;
        }
        self.value = v;
        self.len += n;
    }

    fn finish(mut self) -> Vec<u8> {
        if self.len > 0 {
            put_varint(&mut self.out, self.len << 2 | self.value as u64);
        }
        self.out
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

    #[test]
    fn floods_from_unmarked_cells_label_the_free_regions() {
        let g = Grid::from_ascii("..#.\n#.#.\n");
        let mut seen = vec![false; g.len()];
        assert_eq!(g.reach_into(&[Cell::new(0, 1)], &mut seen), 3);
        assert_eq!(
            g.reach_into(&[Cell::new(1, 0)], &mut seen),
            0,
            "already marked"
        );
        assert_eq!(
            g.reach_into(&[Cell::new(3, 0), Cell::new(2, 0)], &mut seen),
            2
        );
        assert_eq!(seen.iter().filter(|&&s| s).count(), 5);
        assert_eq!(
            g.reachable(&[Cell::new(2, 1)]),
            vec![false; 8],
            "a wall reaches nothing"
        );
    }
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

    /// What [`Grid::to_rle`] wrote before it knew its bounds: every cell read.
    fn rle_of_every_cell(g: &Grid) -> Vec<u8> {
        let mut out = Vec::new();
        put_varint(&mut out, u64::from(g.width()));
        put_varint(&mut out, u64::from(g.height()));
        let cells = g.cells();
        let mut i = 0;
        while i < cells.len() {
            let mut j = i + 1;
            while j < cells.len() && cells[j] == cells[i] {
                j += 1;
            }
            put_varint(&mut out, ((j - i) as u64) << 2 | cells[i] as u64);
            i = j;
        }
        out
    }

    /// A grid of unknown cells with some set, one by one, as robots' grids are built.
    fn arb_sparse_grid() -> impl Strategy<Value = Grid> {
        (1u32..24, 1u32..24).prop_flat_map(|(w, h)| {
            proptest::collection::vec((0..w as i32, 0..h as i32, 0u8..3), 0..40).prop_map(
                move |sets| {
                    let mut g = Grid::new(w, h, Occ::Unknown);
                    for (x, y, v) in sets {
                        g.set(Cell::new(x, y), Occ::from_u8(v).unwrap_or_default());
                    }
                    g
                },
            )
        })
    }

    fn holds_every_known_cell(g: &Grid) -> bool {
        (0..g.len()).all(|i| {
            g.cells()[i] == Occ::Unknown
                || g.known_bounds().is_some_and(|r| r.contains(g.cell_of(i)))
        })
    }

    proptest! {
        #[test]
        fn rle_round_trips(g in arb_grid()) {
            prop_assert_eq!(Grid::from_rle(&g.to_rle()), Ok(g));
        }

        /// The invariant of `known`, and what reads only inside it gives what reading every
        /// cell gives: the same encoding, the same counts, and bounds kept through decoding.
        #[test]
        fn known_bounds_hold_every_known_cell(g in arb_sparse_grid()) {
            prop_assert!(holds_every_known_cell(&g));
            prop_assert_eq!(g.to_rle(), rle_of_every_cell(&g));
            for v in [Occ::Unknown, Occ::Free, Occ::Occupied] {
                prop_assert_eq!(g.count(v), g.cells().iter().filter(|&&c| c == v).count());
            }
            let back = Grid::from_rle(&g.to_rle()).map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert!(holds_every_known_cell(&back));
            prop_assert_eq!(back.to_rle(), rle_of_every_cell(&g));
        }

        /// Decoded in proportion to its known part, a grid is the grid: the same cells, the
        /// same rectangle as the grid's own bounds from the same runs.
        #[test]
        fn the_known_part_decoded_is_the_grids(g in prop_oneof![arb_grid(), arb_sparse_grid()]) {
            let part = KnownPart::from_rle(&g.to_rle()).map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert_eq!(part.to_grid(), g.clone());
            for i in 0..g.len() {
                prop_assert_eq!(part.get(g.cell_of(i)), g.cells()[i]);
            }
            let back = Grid::from_rle(&g.to_rle()).map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert_eq!(part.rect(), back.known_bounds());
            prop_assert_eq!(KnownPart::of(&back), part);
        }

        #[test]
        fn every_cell_read_agrees_on_any_grid(g in arb_grid()) {
            prop_assert!(holds_every_known_cell(&g));
            prop_assert_eq!(g.to_rle(), rle_of_every_cell(&g));
        }

        #[test]
        fn rle_decoding_is_total(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
            let _ = Grid::from_rle(&bytes);
        }
    }
}
