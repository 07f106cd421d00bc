//! One whole robot step (issue #19) — scan integration, contours, approximation and
//! refinement, the merge into the planning grid, frontiers, planning, the radio's sending and
//! the telemetry message — with the same explored region placed in grids of 500², 1 000² and
//! 2 000² cells. The step should cost the same in every grid: work in proportion to the
//! explored part, never to the map's area.
//!
//! The region is a 300 × 300-cell window of intel_lab in the middle of a map that is occupied
//! everywhere else (no beam leaves the window). Four robots (the default scenario: polygon
//! exchange, decentralized coordination) walk fixed tours of its free cells and exchange every
//! radio message for 60 steps; then robot 0's next steps are timed.
//!
//! Run: `cargo bench -p robot-agent --bench step` (medians are what docs/benchmarks.md
//! reports).

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use proto::geom::{MapInfo, Metres, Pose};
use proto::grid::{Cell, Grid, Occ};
use proto::msg::{MoveOutcome, Scan, Step, WorldInfo};
use proto::scenario::Scenario;
use robot_agent::agent::Agent;
use robot_agent::radio::station::Outgoing;

const REGION: u32 = 300;
const ROBOTS: u16 = 4;
const WARM_UP: Step = 60;

/// The truth: intel_lab's central `REGION²` window in the middle of a `size²` map occupied
/// elsewhere.
fn truth(size: u32) -> (Grid, MapInfo) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../configs/maps/intel_lab.yaml");
    let m = world_server::map::load_ros_map(&path).unwrap_or_else(|e| panic!("{e}"));
    let (w, h) = (REGION.min(m.grid.width()), REGION.min(m.grid.height()));
    let (ox, oy) = ((m.grid.width() - w) / 2, (m.grid.height() - h) / 2);
    let at = ((size - w) / 2) as i32;
    let mut g = Grid::new(size, size, Occ::Occupied);
    for y in 0..h as i32 {
        for x in 0..w as i32 {
            let v = m.grid.get(Cell::new(x + ox as i32, y + oy as i32));
            // The window's unknown cells are walls here: nothing to explore beyond them.
            let v = if v == Occ::Free { v } else { Occ::Occupied };
            g.set(Cell::new(x + at, y + at), v);
        }
    }
    (g, MapInfo::at_origin(size, size, m.info.resolution_m))
}

/// Robot `k`'s tour: every 97th free cell of the truth, from its own offset.
fn tour(truth: &Grid, info: &MapInfo, k: usize) -> Vec<Pose> {
    let free: Vec<Cell> = (0..truth.len())
        .map(|i| truth.cell_of(i))
        .filter(|&c| truth.get(c) == Occ::Free)
        .collect();
    let start = free.len() * k / usize::from(ROBOTS);
    (0..free.len() / 97)
        .map(|i| {
            let Metres { x, y } = info.centre_of(free[(start + 97 * i) % free.len()]);
            Pose { x, y, theta: 0.0 }
        })
        .collect()
}

/// The team after the warm-up, and robot 0's tour with where it stands in it.
struct Team {
    truth: Grid,
    info: MapInfo,
    scenario: Scenario,
    agents: Vec<Agent>,
    tours: Vec<Vec<Pose>>,
    step: Step,
}

impl Team {
    fn new(size: u32) -> Team {
        let (truth, info) = truth(size);
        let scenario = Scenario::default();
        let world = WorldInfo {
            map: info,
            laser: scenario.laser(),
            step_seconds: scenario.clock.step_seconds,
            robots: ROBOTS,
            max_speed_m_per_s: scenario.robots.speed_m_per_s,
        };
        let mut agents: Vec<Agent> = (0..ROBOTS)
            .map(|id| Agent::new(id, world.clone(), &scenario))
            .collect();
        let ids: Vec<u16> = (0..ROBOTS).collect();
        let mut greetings = Vec::new();
        for a in &mut agents {
            let others: Vec<u16> = ids.iter().copied().filter(|&p| p != a.id).collect();
            greetings.extend(a.set_neighbours(&others).0);
        }
        let tours = (0..usize::from(ROBOTS))
            .map(|k| tour(&truth, &info, k))
            .collect();
        let mut team = Team {
            truth,
            info,
            scenario,
            agents,
            tours,
            step: 0,
        };
        team.deliver(greetings);
        for _ in 0..WARM_UP {
            team.all_step();
        }
        team
    }

    fn scan(&self, k: usize) -> Scan {
        let tour = &self.tours[k];
        let pose = tour[self.step as usize % tour.len()];
        Scan {
            step: self.step,
            pose,
            ranges: world_server::laser::cast(
                &self.truth,
                &self.info,
                pose,
                &self.scenario.laser(),
                None,
            ),
            last_move: MoveOutcome::Start,
        }
    }

    /// Every robot's step, every message delivered.
    fn all_step(&mut self) {
        let scans: Vec<Scan> = (0..self.agents.len()).map(|k| self.scan(k)).collect();
        let mut out = Vec::new();
        for (a, scan) in self.agents.iter_mut().zip(&scans) {
            a.on_scan(scan);
            out.extend(a.radio_step());
            out.extend(a.frames());
        }
        self.deliver(out);
        self.step += 1;
    }

    /// Delivers `out`, and the answers it brings, until none is left.
    fn deliver(&mut self, mut out: Vec<Outgoing>) {
        while let Some(o) = out.pop() {
            let kind = proto::keys::radio_kind(&o.key).unwrap_or("").to_string();
            let to = &mut self.agents[usize::from(o.to)];
            out.extend(to.on_radio(&kind, &o.bytes));
        }
    }

    /// Robot 0's step as its process does it: the scan, the radio's sending, the telemetry.
    fn robot_step(&mut self) -> usize {
        let scan = self.scan(0);
        let a = &mut self.agents[0];
        a.on_scan(&scan);
        let mut out = a.radio_step();
        out.extend(a.frames());
        let sent: usize = out.iter().map(|o| o.bytes.len()).sum();
        self.step += 1;
        sent + proto::msg::encode(&a.telemetry()).len()
    }
}

fn step_by_grid_size(c: &mut Criterion) {
    let mut group = c.benchmark_group("robot_step_by_grid_size");
    group.sample_size(30);
    for size in [500u32, 1000, 2000] {
        let mut team = Team::new(size);
        group.bench_function(BenchmarkId::from_parameter(format!("{size}x{size}")), |b| {
            b.iter(|| team.robot_step())
        });
    }
    group.finish();
}

criterion_group!(benches, step_by_grid_size);
criterion_main!(benches);
