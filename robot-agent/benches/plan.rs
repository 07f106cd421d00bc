//! The searches a robot runs every step (issue #40), over a campus-sized known map: the way to a
//! kept target (`path_until`, A*) and a search all over (`costs_into`, Dijkstra).
//!
//! The map is mit_killian_court's truth at its native 0.2 m (about 1 000 × 800 cells), as a
//! robot knows it late in a complete run. The ways are between fixed pairs of free cells 150
//! to 450 cells of path apart — the kind of way a robot keeps late in that run, when the
//! frontiers left are far (the A* ways of the last tenth of the 8-robot run: 354 cells long on
//! average).
//!
//! Run: `cargo bench -p robot-agent --bench plan` (medians are what docs/benchmarks.md
//! reports).

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use proto::grid::{Cell, Grid, Occ};
use robot_agent::nav::plan::{self, CostMap};

const WAYS: usize = 16;

fn campus() -> Grid {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../configs/maps/mit_killian_court.yaml");
    world_server::map::load_ros_map(&path)
        .unwrap_or_else(|e| panic!("{e}"))
        .grid
}

/// `WAYS` (start, target) pairs of free cells whose cheapest path costs 150 to 450, picked by a
/// fixed stride through the free cells.
fn ways(g: &Grid) -> Vec<(Cell, Cell)> {
    let free: Vec<Cell> = (0..g.len())
        .map(|i| g.cell_of(i))
        .filter(|&c| g.get(c) == Occ::Free)
        .collect();
    let mut out = Vec::new();
    let mut k = 0usize;
    while out.len() < WAYS && k < 100_000 {
        let s = free[(k * 7_919) % free.len()];
        let t = free[(k * 104_729 + 13) % free.len()];
        k += 1;
        let costs = plan::costs_with(g, s, None);
        if costs.cost(t).is_some_and(|c| (150.0..450.0).contains(&c)) {
            out.push((s, t));
        }
    }
    assert_eq!(out.len(), WAYS, "the map has too few such ways");
    out
}

fn searches(c: &mut Criterion) {
    let g = campus();
    let ways = ways(&g);
    let mut group = c.benchmark_group("campus_search");
    group.sample_size(20);
    let mut map = CostMap::default();
    // A step later: each robot two cells along its way, the way of the step before known.
    let later: Vec<(Cell, Cell, Vec<Cell>)> = ways
        .iter()
        .map(|&(s, t)| {
            let way = plan::path_until(&mut map, &g, s, None, t).expect("a way");
            (way[2], t, way)
        })
        .collect();
    for (s, t, way) in &later {
        assert_eq!(
            plan::path_until(&mut map, &g, *s, None, *t),
            plan::path_along(&mut map, &g, *s, None, *t, way)
        );
    }
    group.bench_function("path_until_16_ways_a_step_later", |b| {
        b.iter(|| {
            later
                .iter()
                .map(|(s, t, _)| {
                    plan::path_until(&mut map, &g, *s, None, *t).map_or(0, |p| p.len())
                })
                .sum::<usize>()
        })
    });
    group.bench_function("path_along_16_ways_a_step_later", |b| {
        b.iter(|| {
            later
                .iter()
                .map(|(s, t, way)| {
                    plan::path_along(&mut map, &g, *s, None, *t, way).map_or(0, |p| p.len())
                })
                .sum::<usize>()
        })
    });
    group.bench_function("costs_into_all", |b| {
        b.iter(|| {
            plan::costs_into(&mut map, &g, ways[0].0, None);
            map.cost(ways[0].1)
        })
    });
    group.finish();
}

criterion_group!(benches, searches);
criterion_main!(benches);
