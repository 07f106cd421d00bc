//! One world-server step (issue #19): every robot's laser scan and the moves of its command,
//! with the same explored region placed in truth maps of 500², 1 000² and 2 000² cells. It
//! should cost the same in every map: per beam and per robot, never per cell of the map.
//!
//! The region is a 300 × 300-cell window of intel_lab in the middle of a map occupied
//! everywhere else, written as a ROS map (PGM + YAML) and loaded as any user's map is; eight
//! robots (the default scenario otherwise) move back and forth by a few centimetres.
//!
//! Run: `cargo bench -p world-server --bench step` (medians are what docs/benchmarks.md
//! reports).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use proto::geom::Metres;
use proto::grid::{Cell, Occ};
use proto::msg::{Cmd, RobotId, Step};
use proto::scenario::Scenario;
use world_server::shipped::MapSource;
use world_server::world::World;

const REGION: u32 = 300;
const ROBOTS: u16 = 8;

/// Writes the truth map of `size²` cells into `dir` as a ROS map; returns its YAML and
/// resolution.
fn write_truth(dir: &Path, size: u32) -> (PathBuf, f64) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../configs/maps/intel_lab.yaml");
    let m = world_server::map::load_ros_map(&path).unwrap_or_else(|e| panic!("{e}"));
    let (w, h) = (REGION.min(m.grid.width()), REGION.min(m.grid.height()));
    let (ox, oy) = ((m.grid.width() - w) / 2, (m.grid.height() - h) / 2);
    let at = ((size - w) / 2) as i32;
    // PGM rows run from the top of the map; free 254, everything else occupied (0).
    let mut pgm = format!("P5\n{size} {size}\n255\n").into_bytes();
    for row in 0..size as i32 {
        let y = size as i32 - 1 - row;
        for x in 0..size as i32 {
            let (rx, ry) = (x - at, y - at);
            let inside = (0..w as i32).contains(&rx) && (0..h as i32).contains(&ry);
            let free = inside && m.grid.get(Cell::new(rx + ox as i32, ry + oy as i32)) == Occ::Free;
            pgm.push(if free { 254 } else { 0 });
        }
    }
    let image = dir.join(format!("truth_{size}.pgm"));
    std::fs::write(&image, pgm).unwrap_or_else(|e| panic!("{e}"));
    let yaml = dir.join(format!("truth_{size}.yaml"));
    let text = format!(
        "image: {}\nresolution: {}\norigin: [0.0, 0.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
        image.display(),
        m.info.resolution_m
    );
    std::fs::write(&yaml, text).unwrap_or_else(|e| panic!("{e}"));
    (yaml, m.info.resolution_m)
}

fn step_by_map_size(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("world-step-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
    let mut group = c.benchmark_group("world_step_by_map_size");
    group.sample_size(30);
    for size in [500u32, 1000, 2000] {
        let (yaml, resolution) = write_truth(&dir, size);
        let mut s = Scenario::default();
        s.world.map = format!("truth_{size}");
        s.world.resolution_m = resolution;
        s.robots.count = ROBOTS;
        let mut world =
            World::build(&s, Some(&MapSource::File(yaml))).unwrap_or_else(|e| panic!("{e}"));
        let mut step: Step = 0;
        group.bench_function(BenchmarkId::from_parameter(format!("{size}x{size}")), |b| {
            b.iter(|| {
                let scans: usize = (0..ROBOTS)
                    .filter_map(|id| world.scan(id, step))
                    .map(|scan| scan.ranges.len())
                    .sum();
                let dx = if step.is_multiple_of(2) { 0.05 } else { -0.05 };
                let cmds: HashMap<RobotId, Cmd> = (world.bodies.iter())
                    .map(|b| {
                        let waypoint = Some(Metres::new(b.pose.x + dx, b.pose.y));
                        let cmd = Cmd {
                            step,
                            robot: b.id,
                            waypoint,
                        };
                        (b.id, cmd)
                    })
                    .collect();
                world.apply(step, &cmds);
                step += 1;
                scans
            })
        });
    }
    group.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, step_by_map_size);
criterion_main!(benches);
