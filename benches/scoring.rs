//! The launcher's scoring of one telemetry message (issue #19): decoding the robot's planning
//! grid, coverage, correct cells and team awareness, with the same explored region placed in
//! truth maps of 500², 1 000² and 2 000² cells. It should cost the same in every map: work in
//! proportion to the explored part, never to the map's area.
//!
//! The region is a 300 × 300-cell window of intel_lab in the middle of a map occupied
//! everywhere else; robot 0 reports, in turn, a planning grid that knows all of the region and
//! one that knows its lower half (so each message changes what the team knows).
//!
//! Run: `cargo bench -p swarm --bench scoring` (medians are what docs/benchmarks.md reports).

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, BatchSize, BenchmarkId, Criterion};
use proto::grid::{Cell, Grid, Occ};
use proto::grid_report::GridReport;
use proto::msg::Telemetry;
use swarm::score::evaluate::Evaluator;

const REGION: u32 = 300;
const ROBOTS: u16 = 8;

/// The truth (intel_lab's central `REGION²` window in the middle of a `size²` map occupied
/// elsewhere) and the window's corner.
fn truth(size: u32) -> (Grid, Cell) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs/maps/intel_lab.yaml");
    let m = world_server::map::load_ros_map(&path).unwrap_or_else(|e| panic!("{e}"));
    let (w, h) = (REGION.min(m.grid.width()), REGION.min(m.grid.height()));
    let (ox, oy) = ((m.grid.width() - w) / 2, (m.grid.height() - h) / 2);
    let at = Cell::new(((size - w) / 2) as i32, ((size - h) / 2) as i32);
    let mut g = Grid::new(size, size, Occ::Occupied);
    for y in 0..h as i32 {
        for x in 0..w as i32 {
            let v = m.grid.get(Cell::new(x + ox as i32, y + oy as i32));
            let v = if v == Occ::Free { v } else { Occ::Occupied };
            g.set(Cell::new(x + at.x, y + at.y), v);
        }
    }
    (g, at)
}

/// A robot's planning grid that knows the rows `0..rows` of the region.
fn planning(truth: &Grid, at: Cell, rows: i32) -> Grid {
    let mut g = Grid::new(truth.width(), truth.height(), Occ::Unknown);
    for y in 0..rows {
        for x in 0..REGION as i32 {
            let c = Cell::new(x + at.x, y + at.y);
            g.set(c, truth.get(c));
        }
    }
    g
}

fn scoring_by_map_size(c: &mut Criterion) {
    let mut group = c.benchmark_group("launcher_scoring_by_map_size");
    group.sample_size(30);
    for size in [500u32, 1000, 2000] {
        let (truth, at) = truth(size);
        let reports: Vec<Telemetry> = [REGION as i32, REGION as i32 / 2]
            .into_iter()
            .map(|rows| Telemetry {
                grid: GridReport::Whole(planning(&truth, at, rows).to_rle()),
                ..Telemetry::default()
            })
            .collect();
        let mut ev = Evaluator::new(truth.clone(), &truth, 95.0).with_team(ROBOTS);
        let mut k = 0usize;
        group.bench_function(BenchmarkId::from_parameter(format!("{size}x{size}")), |b| {
            b.iter_batched(
                || {
                    k += 1;
                    Telemetry {
                        step: k as u32,
                        ..reports[k % 2].clone()
                    }
                },
                |t| ev.add(t),
                BatchSize::SmallInput,
            )
        });
    }
    group.finish();
}

criterion_group!(benches, scoring_by_map_size);
criterion_main!(benches);
