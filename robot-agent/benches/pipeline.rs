//! Benchmarks of the mapping pipeline (issue #4): one full step (scan integration → contours →
//! approximation + refinement → delta → encoding → merge of 3 peers' approximations) and each
//! stage alone, on windows of real maps at their native resolution: 300×300 cells of intel_lab
//! and 1000×1000 cells of aces3_austin. Contour extraction is also measured on growing windows,
//! with throughput in contour points, and with one fixed room in growing grids, to show it is
//! linear in the number of contour pixels and independent of the grid's area.
//!
//! Run: `cargo bench -p robot-agent` (medians are what the docs report).

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, BatchSize, BenchmarkId, Criterion, Throughput};
use proto::geom::{LaserSpec, MapInfo, Metres, Pose};
use proto::grid::{Cell, Grid, Occ};
use robot_agent::exchange::delta::diff;
use robot_agent::exchange::wire::encode;
use robot_agent::mapping::approx::Approximation;
use robot_agent::mapping::approximator::Approximator;
use robot_agent::mapping::contour::{ContourPixels, Contours};
use robot_agent::mapping::grid::Evidence;
use robot_agent::mapping::merge::merge;
use robot_agent::mapping::render::ExplorationView;
use robot_agent::nav::plan::{self, CostMap};

const SPLITS: f64 = 2.0;

fn laser() -> LaserSpec {
    LaserSpec {
        beams: 360,
        fov_rad: std::f64::consts::TAU,
        max_range_m: 8.0,
        noise_std_m: 0.0,
    }
}

/// A `size × size` window of a shipped map (cut from its centre), with its frame.
fn window(map: &str, size: u32) -> (Grid, MapInfo) {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("../configs/maps/{map}.yaml"));
    let m = world_server::map::load_ros_map(&path).unwrap_or_else(|e| panic!("{e}"));
    let (w, h) = (size.min(m.grid.width()), size.min(m.grid.height()));
    let (ox, oy) = ((m.grid.width() - w) / 2, (m.grid.height() - h) / 2);
    let mut g = Grid::new(w, h, Occ::Unknown);
    for y in 0..h as i32 {
        for x in 0..w as i32 {
            g.set(
                Cell::new(x, y),
                m.grid.get(Cell::new(x + ox as i32, y + oy as i32)),
            );
        }
    }
    let info = MapInfo::at_origin(w, h, m.info.resolution_m);
    (g, info)
}

/// Free cells of the truth visited in a fixed order: a deterministic "trajectory".
fn poses(truth: &Grid, info: &MapInfo, n: usize) -> Vec<Pose> {
    let free: Vec<Cell> = (0..truth.len())
        .map(|i| truth.cell_of(i))
        .filter(|&c| truth.get(c) == Occ::Free)
        .collect();
    let stride = (free.len() / n.max(1)).max(1);
    free.iter()
        .step_by(stride)
        .take(n)
        .map(|&c| {
            let Metres { x, y } = info.centre_of(c);
            Pose { x, y, theta: 0.0 }
        })
        .collect()
}

/// A robot's state after integrating `scans` scans: G_s, its evidence, its approximator.
#[derive(Clone)]
struct State {
    own: Grid,
    evidence: Evidence,
    /// P_t, kept from step to step (as the robot's mapper keeps it).
    contours: Contours,
    /// G_s's exploration view, kept up to date from the changed cells (as the robot's mapper
    /// keeps it).
    view: ExplorationView,
    approximator: Approximator,
    previous: Approximation,
}

fn explore(truth: &Grid, info: &MapInfo, path: &[Pose]) -> State {
    let own = Grid::new(truth.width(), truth.height(), Occ::Unknown);
    let mut s = State {
        evidence: Evidence::new(&own),
        contours: Contours::extract(&own),
        view: ExplorationView::new(&own),
        own,
        approximator: Approximator::new(),
        previous: Approximation::default(),
    };
    for &p in path {
        let ranges = world_server::laser::cast(truth, info, p, &laser(), None);
        let changed = s.evidence.integrate(&mut s.own, info, p, &ranges, &laser());
        s.contours.update(&s.own, &changed);
        s.view.update(&s.own, changed);
        s.previous = s
            .approximator
            .step_in_view(&s.contours, s.view.grid(), SPLITS)
            .clone();
    }
    s
}

/// One full step from `s`: integrate the scan at `p`, then the whole mapping pipeline and a
/// merge with three peers' approximations.
fn full_step(
    mut s: State,
    truth: &Grid,
    info: &MapInfo,
    p: Pose,
    peers: &[&Approximation],
) -> (usize, Grid) {
    let ranges = world_server::laser::cast(truth, info, p, &laser(), None);
    let changed = s.evidence.integrate(&mut s.own, info, p, &ranges, &laser());
    s.contours.update(&s.own, &changed);
    s.view.update(&s.own, changed);
    let a = s
        .approximator
        .step_in_view(&s.contours, s.view.grid(), SPLITS)
        .clone();
    let ops = diff(&s.previous, &a);
    let bytes = encode(&ops).len();
    (bytes, merge(&s.own, peers))
}

fn pipeline(c: &mut Criterion, map: &str, size: u32) {
    let (truth, info) = window(map, size);
    let path = poses(&truth, &info, 40);
    let (walk, next) = path.split_at(path.len() - 1);
    let me = explore(&truth, &info, walk);
    // Three peers that explored other parts of the window.
    let peer_states: Vec<State> = (0..3)
        .map(|k| explore(&truth, &info, &poses(&truth, &info, 40 + 7 * k)[..20]))
        .collect();
    let peers: Vec<&Approximation> = peer_states.iter().map(|s| &s.previous).collect();
    let p = next[0];
    let mut group = c.benchmark_group(format!("pipeline_{size}x{size}_{map}"));
    group.sample_size(20);
    group.bench_function("full_step", |b| {
        b.iter_batched(
            || me.clone(),
            |s| full_step(s, &truth, &info, p, &peers),
            BatchSize::LargeInput,
        )
    });
    let ranges = world_server::laser::cast(&truth, &info, p, &laser(), None);
    group.bench_function("integrate_scan", |b| {
        b.iter_batched(
            || me.clone(),
            |mut s| {
                s.evidence
                    .integrate(&mut s.own, &info, p, &ranges, &laser())
            },
            BatchSize::LargeInput,
        )
    });
    let mut after = me.clone();
    let changed = after
        .evidence
        .integrate(&mut after.own, &info, p, &ranges, &laser());
    group.bench_function("exploration_view_update", |b| {
        b.iter_batched(
            || me.view.clone(),
            |mut v| v.update(&after.own, changed.iter().copied()),
            BatchSize::LargeInput,
        )
    });
    after.view.update(&after.own, changed.iter().copied());
    group.bench_function("contour", |b| {
        b.iter_batched(
            || me.contours.clone(),
            |mut p| p.update(&after.own, &changed),
            BatchSize::LargeInput,
        )
    });
    let contours = Contours::extract(&after.own);
    group.bench_function("approx_refine", |b| {
        b.iter_batched(
            || after.approximator.clone(),
            |mut ax| {
                ax.step_in_view(&contours, after.view.grid(), SPLITS)
                    .vertex_count()
            },
            BatchSize::LargeInput,
        )
    });
    let a = after
        .approximator
        .clone()
        .step_in_view(&contours, after.view.grid(), SPLITS)
        .clone();
    group.bench_function("delta", |b| b.iter(|| diff(&after.previous, &a)));
    let ops = diff(&after.previous, &a);
    group.bench_function("encode", |b| b.iter(|| encode(&ops)));
    group.bench_function("merge_3_peers", |b| b.iter(|| merge(&after.own, &peers)));
    group.finish();
}

fn pipelines(c: &mut Criterion) {
    pipeline(c, "intel_lab", 300);
    pipeline(c, "aces3_austin", 1000);
}

/// Contour extraction on fully known windows of growing size, with the contour pixels known
/// (kept up to date step by step): time per contour point should stay flat.
fn contour_scaling(c: &mut Criterion) {
    let mut group = c.benchmark_group("contour_scaling_aces3_austin");
    group.sample_size(20);
    for size in [125u32, 250, 500, 1000] {
        let (truth, _) = window("aces3_austin", size);
        let pixels = ContourPixels::scan(&truth);
        let points = Contours::extract_at(&truth, &pixels).len() as u64;
        group.throughput(Throughput::Elements(points));
        group.bench_with_input(
            BenchmarkId::from_parameter(format!("{size}x{size} ({points} contour points)")),
            &truth,
            |b, g| b.iter(|| Contours::extract_at(g, &pixels)),
        );
    }
    group.finish();
}

/// One explored 100×100-cell room (walls, a pillar, a doorway into unknown space) in grids of
/// growing area: extraction from the kept contour pixels costs the same in every grid, while
/// a scan of every cell (the thesis's Algorithm 3 step 1, [`ContourPixels::scan`]) grows with
/// the area.
fn contour_fixed_room(c: &mut Criterion) {
    let mut group = c.benchmark_group("contour_fixed_room");
    group.sample_size(20);
    for size in [250u32, 500, 1000, 2000] {
        let mut g = Grid::new(size, size, Occ::Unknown);
        let o = (size / 2 - 50) as i32;
        for y in 0..100 {
            for x in 0..100 {
                let wall = x == 0 || y == 0 || x == 99 || y == 99;
                let pillar = (40..60).contains(&x) && (40..60).contains(&y);
                let door = x == 99 && (45..55).contains(&y);
                let v = if door {
                    Occ::Free
                } else if wall || pillar {
                    Occ::Occupied
                } else {
                    Occ::Free
                };
                g.set(Cell::new(o + x, o + y), v);
            }
        }
        let pixels = ContourPixels::scan(&g);
        group.bench_with_input(
            BenchmarkId::new("extract_at", format!("{size}x{size}")),
            &g,
            |b, g| b.iter(|| Contours::extract_at(g, &pixels)),
        );
        group.bench_with_input(
            BenchmarkId::new("scan_every_cell", format!("{size}x{size}")),
            &g,
            |b, g| b.iter(|| ContourPixels::scan(g)),
        );
    }
    group.finish();
}

/// A robot's full path search (every frontier's cost, as a strategy choosing a target needs)
/// over the whole of mit_killian_court known: the campus-sized search late in a run.
fn full_search(c: &mut Criterion) {
    let (truth, _) = window("mit_killian_court", 100_000);
    let start = (0..truth.len())
        .map(|i| truth.cell_of(i))
        .filter(|&c| truth.get(c) == Occ::Free)
        .nth(truth.count(Occ::Free) / 2)
        .expect("a free cell");
    let mut group = c.benchmark_group("full_search_mit_killian_court");
    group.sample_size(20);
    let mut costs = CostMap::default();
    group.bench_function("costs", |b| {
        b.iter(|| plan::costs_into(&mut costs, &truth, start, None))
    });
    group.finish();
}

criterion_group!(
    benches,
    pipelines,
    contour_scaling,
    contour_fixed_room,
    full_search
);
criterion_main!(benches);
