//! The mapping pipeline of one robot, thesis Algorithm 10 steps 2–5 (docs/design.md §4): extract the
//! exact polygonal model P_t of G_s (§4.1), derive and refine the approximation A_t (§4.2, §4.3),
//! append the edit operations A_{t−1} → A_t and a save point to the own op log (§4.2.3), and
//! measure what that costs on the wire (Table 6.1) and how far A_t is from G_s (eq. 6.1).
//!
//! Pure composition of [`crate::mapping::contour`], [`crate::mapping::approx`], [`crate::exchange::oplog`], [`crate::exchange::wire`]
//! and [`crate::mapping::approx_error`]; the exchange of the log is another module's job.

use proto::grid::{Cell, Grid, Occ, Rect};
use proto::msg::Traffic;

use crate::exchange::oplog::OpLog;
use crate::exchange::wire::Encoder;
use crate::mapping::approx::Approximation;
use crate::mapping::approx_error::KeptError;
use crate::mapping::approximator::Approximator;
use crate::mapping::contour::Contours;
use crate::mapping::render::ExplorationView;

/// Counts and encoded bytes of every op appended so far, per package type (indexed by
/// [`Traffic`]; only its [`Traffic::OPS`] ever count).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct OpStats {
    pub count: [u64; Traffic::ALL.len()],
    pub bytes: [u64; Traffic::ALL.len()],
}

impl OpStats {
    /// Mean encoded bytes of one op of type `t` (`None` if there was none).
    pub fn mean_bytes(&self, t: Traffic) -> Option<f64> {
        let i = t as usize;
        (self.count[i] > 0).then(|| self.bytes[i] as f64 / self.count[i] as f64)
    }
}

/// What one step did.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StepReport {
    /// Points of P_t and its objects.
    pub contour_points: usize,
    pub objects: usize,
    /// Vertices of A_t.
    pub vertices: usize,
    /// Ops appended this step (0 when A_t = A_{t−1}), and their encoded bytes in one chunk.
    pub ops: usize,
    pub bytes: usize,
    /// Douglas–Peucker splits made this step.
    pub splits: usize,
    /// d_t: cells where G_s and the rendered A_t differ (eq. 6.1).
    pub error_cells: usize,
    /// Cells of G_s that are not unknown.
    pub known_cells: usize,
}

#[derive(Clone, Debug)]
pub struct Mapper {
    approximator: Approximator,
    contours: Option<Contours>,
    /// G_s's exploration view, kept up to date from the changed cells, and d_t, kept where
    /// the view or the approximation changed.
    view: Option<(ExplorationView, KeptError)>,
    /// G_s's known cells: per cell whether it was known at the last step, and how many were.
    known: Vec<bool>,
    known_cells: usize,
    log: OpLog,
    previous: Approximation,
    /// `previous`'s [`Approximation::digest`], computed when it changed (a full pass over it:
    /// late in a big map, thousands of vertices that most steps leave as they were).
    digest: u64,
    /// Douglas–Peucker splits per step (fractional values accumulate).
    pub splits_per_step: f64,
    /// Whether the logged approximation keeps its edges' error bounds
    /// (`exchange.edge_bounds`; without them, the thesis's).
    pub edge_bounds: bool,
    pub stats: OpStats,
    /// Σ d_t and Σ known cells over all steps (for e_avg).
    error_sum: u64,
    known_sum: u64,
    steps: u64,
}

impl Mapper {
    pub fn new(splits_per_step: f64) -> Mapper {
        Mapper {
            approximator: Approximator::new(),
            contours: None,
            view: None,
            known: Vec::new(),
            known_cells: 0,
            log: OpLog::new(),
            previous: Approximation::default(),
            digest: Approximation::default().digest(),
            splits_per_step,
            edge_bounds: true,
            stats: OpStats::default(),
            error_sum: 0,
            known_sum: 0,
            steps: 0,
        }
    }

    /// Runs steps 2–5 of Algorithm 10 on the current self-explored grid `own`, of which only
    /// the cells `changed` changed since the previous step (all of them count as changed at the
    /// first step).
    pub fn step(&mut self, own: &Grid, changed: &[Cell]) -> StepReport {
        let p = match self.contours.take() {
            Some(mut p) => {
                p.update(own, changed);
                p
            }
            None => Contours::extract(own),
        };
        let (view, error) = match self.view.as_mut() {
            Some((v, e)) => {
                // The view of a cell follows it and its 4-neighbours.
                let region = Rect::around(changed.iter().copied()).map(|r| r.grown(1));
                region.iter().for_each(|&r| e.before_view(v.grid(), r));
                v.update(own, changed.iter().copied());
                region.iter().for_each(|&r| e.after_view(v.grid(), r));
                (v, e)
            }
            None => {
                let v = ExplorationView::new(own);
                let e = KeptError::new(v.grid());
                let (v, e) = self.view.insert((v, e));
                (v, e)
            }
        };
        let mut a = self
            .approximator
            .step_in_view(&p, view.grid(), self.splits_per_step)
            .clone();
        if !self.edge_bounds {
            a.drop_bounds();
        }
        let first = self.log.len();
        let ops = self.log.record(&self.previous, &a);
        let mut enc = Encoder::new();
        for op in self.log.since(first) {
            let b = enc.push(op);
            let i = op.kind() as usize;
            self.stats.count[i] += 1;
            self.stats.bytes[i] += b as u64;
        }
        let bytes = enc.finish().len();
        let error_cells = error.error(view.grid(), &a);
        let known_cells = self.count_known(own, changed);
        self.error_sum += error_cells as u64;
        self.known_sum += known_cells as u64;
        self.steps += 1;
        let report = StepReport {
            contour_points: p.len(),
            objects: p.objects().len(),
            vertices: a.vertex_count(),
            ops,
            bytes,
            splits: self.approximator.last_refinement().splits,
            error_cells,
            known_cells,
        };
        if ops > 0 {
            // The ops are empty exactly when A_t is A_{t-1} (`delta::diff`).
            self.digest = a.digest();
        }
        self.previous = a;
        self.contours = Some(p);
        report
    }

    /// G_s's known cells, counted where they changed (all of them at the first step).
    fn count_known(&mut self, own: &Grid, changed: &[Cell]) -> usize {
        if self.known.len() != own.len() {
            self.known = own.cells().iter().map(|&c| c != Occ::Unknown).collect();
            self.known_cells = self.known.iter().filter(|&&k| k).count();
            return self.known_cells;
        }
        for &c in changed {
            let Some(i) = own.index(c) else { continue };
            let now = own.get(c) != Occ::Unknown;
            if now != self.known[i] {
                self.known[i] = now;
                self.known_cells = if now {
                    self.known_cells + 1
                } else {
                    self.known_cells - 1
                };
            }
        }
        self.known_cells
    }

    /// P_t of the last step.
    pub fn contours(&self) -> Option<&Contours> {
        self.contours.as_ref()
    }

    /// A_t of the last step.
    pub fn approximation(&self) -> &Approximation {
        &self.previous
    }

    /// A_t's [`Approximation::digest`].
    pub fn digest(&self) -> u64 {
        self.digest
    }

    pub fn log(&self) -> &OpLog {
        &self.log
    }

    /// e_avg over the steps so far: Σ d_t / Σ known cells (eq. 6.1 with g·n the explored cells
    /// summed over the steps).
    pub fn error_avg(&self) -> Option<f64> {
        (self.known_sum > 0).then(|| self.error_sum as f64 / self.known_sum as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::exchange::oplog::Replica;

    #[test]
    fn the_log_replays_to_the_current_approximation_and_its_digest_is_kept() {
        let frames = [
            "??????????\n??????????\n???....???\n??????????\n",
            "??????????\n??#....#??\n??#....#??\n??######??\n",
            "?########?\n?#......#?\n?#..##..#?\n?########?\n",
            "?########?\n?#......#?\n?#..##..#?\n?########?\n",
        ];
        let mut m = Mapper::new(3.0);
        let mut before = Grid::from_ascii(frames[0]);
        for f in frames {
            let g = Grid::from_ascii(f);
            let changed: Vec<Cell> = (0..g.len())
                .filter(|&i| g.cells()[i] != before.cells()[i])
                .map(|i| Cell::new((i % 10) as i32, (i / 10) as i32))
                .collect();
            let r = m.step(&g, &changed);
            assert!(r.vertices > 0);
            assert_eq!(r.contour_points, Contours::extract(&g).len());
            // The digest kept is the approximation's, whether the step changed it or not.
            assert_eq!(m.digest(), m.approximation().digest());
            before = g;
        }
        let mut replica = Replica::new();
        for op in m.log().since(0) {
            replica.apply(op).unwrap_or_else(|e| panic!("{e:?}"));
        }
        assert_eq!(replica.committed(), m.approximation());
        let total: u64 = m.stats.count.iter().sum();
        assert_eq!(total as usize, m.log().len());
        assert!(m.error_avg().is_some());
    }

    /// `exchange.edge_bounds = false` logs the thesis's approximation: the same vertices, no
    /// edge with an error bound.
    #[test]
    fn without_edge_bounds_the_log_carries_none() {
        let g = Grid::from_ascii("?########?\n?#......#?\n?#..##..#?\n?#......#?\n?########?\n");
        let all: Vec<Cell> = (0..g.len())
            .map(|i| Cell::new((i % 10) as i32, (i / 10) as i32))
            .collect();
        let bounded = |edge_bounds: bool| {
            let mut m = Mapper::new(0.0);
            m.edge_bounds = edge_bounds;
            m.step(&g, &all);
            let vertices: Vec<_> = m
                .log()
                .since(0)
                .iter()
                .filter_map(|op| match op {
                    crate::exchange::delta::Op::Insert { v, .. } => Some(v.bound),
                    _ => None,
                })
                .collect();
            (vertices.len(), vertices.iter().filter(|&&b| b != 0).count())
        };
        let (with, without) = (bounded(true), bounded(false));
        assert_eq!(with.0, without.0);
        assert!(with.1 > 0, "a coarse approximation has bounded edges");
        assert_eq!(without.1, 0);
    }
}
