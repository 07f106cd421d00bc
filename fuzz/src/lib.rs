//! Fuzz targets for every decoder of data from outside a process, one function per target
//! (`fuzz_targets/<name>.rs` hands libFuzzer's input to it). Each must return for any input —
//! no panic, no hang, no unbounded allocation — which is what the fuzzer checks:
//!
//! * [`sim_plane`] — every sim-plane message (status, scan, command, telemetry, link plan,
//!   control, world info, truth, link report, process order, what a robot holds) and the run-length grids inside
//!   them; a decoded scan is handed to a robot, which integrates it and plans;
//! * [`radio`] — every radio payload kind as a robot receives it, taken into a robot of one of
//!   the strategies and exchange modes, which then (as the input chooses) integrates a scan and
//!   plans;
//! * [`op_chunk`] — the compact op encoding (thesis Table 6.1) and applying the ops to a replica;
//! * [`scenario`] — scenario TOML, `--set` overrides, link and process faults;
//! * [`map_yaml`] and [`map_image`] — ROS map_server YAML and PGM/PNG images;
//! * [`netem_http`] — netem's control API: its JSON request bodies (proxy updates, toxics,
//!   process faults; HTTP itself is hyper's).
//!
//! The committed corpora (`corpus/<target>/`) are valid inputs to start from, written by the
//! ignored test `write_seed_corpus` (robots really exchanging, the project's maps and
//! scenarios). Without libFuzzer, the smoke test runs every target over its corpus and over
//! seeded random mutations of it (the bounded run CI does: `cargo test --release
//! --manifest-path fuzz/Cargo.toml`).

use std::path::Path;

use proto::geom::{LaserSpec, MapInfo, Pose};
use proto::grid::Grid;
use proto::keys::RADIO_KINDS;
use proto::msg::{
    decode, Cmd, Control, LinkPlan, LinkReport, MoveOutcome, ProcessOrder, Scan, Status,
    Telemetry, TruthMap, WorldInfo,
};
use proto::scenario::{ExchangeMode, Scenario, Strategy};
use robot_agent::agent::Agent;

/// A small world for a robot to act in: 40 × 40 cells of 0.1 m, a 36-beam laser (small, so a
/// long fuzzing run gets through its ten million inputs in hours, not days).
fn world(robots: u16) -> WorldInfo {
    WorldInfo {
        map: MapInfo::at_origin(40, 40, 0.1),
        laser: LaserSpec {
            beams: 36,
            fov_rad: std::f64::consts::TAU,
            max_range_m: 2.0,
            noise_std_m: 0.0,
        },
        step_seconds: 1.0,
        robots,
        max_speed_m_per_s: 0.5,
    }
}

/// A scan that sees a free disk around the middle of [`world`].
fn plain_scan(step: u32) -> Scan {
    Scan {
        step,
        pose: Pose {
            x: 2.0,
            y: 2.0,
            theta: 0.0,
        },
        ranges: vec![1.5; 36],
        last_move: MoveOutcome::Stayed,
    }
}

/// A robot of a 3-robot team (id 1) with `strategy` and `mode`; a base station where the
/// strategy needs one.
fn agent(strategy: Strategy, mode: ExchangeMode) -> Agent {
    let mut s = Scenario::default();
    s.robots.count = 3;
    s.coordination.strategy = strategy;
    s.exchange.mode = mode;
    s.base_station.enabled = matches!(strategy, Strategy::Bids | Strategy::Roles);
    Agent::new(1, world(s.nodes()), &s)
}

/// Sim-plane messages: each decoder over the whole input; what decodes is used as its receiver
/// would use it.
pub fn sim_plane(data: &[u8]) {
    if let Ok(st) = decode::<Status>(data) {
        let _ = st.robots.iter().filter(|r| r.alive).count();
    }
    if let Ok(scan) = decode::<Scan>(data) {
        let mut a = agent(Strategy::Decentralized, ExchangeMode::Polygon);
        let _ = a.on_scan(&scan);
        let _ = a.telemetry();
    }
    let _ = decode::<Cmd>(data);
    if let Ok(t) = decode::<Telemetry>(data) {
        // As the launcher takes a report: a whole grid, then changes of it.
        let mut held = proto::grid_report::Received::new(8, 6);
        let _ = held.apply(t.step, &t.grid);
        let _ = held.apply(t.step.wrapping_add(1), &t.own);
        let _ = held.apply(t.step, &t.grid);
    }
    if let Ok(plan) = decode::<LinkPlan>(data) {
        let _ = plan.neighbours(1);
        for peer in 0..4 {
            if let Some(l) = plan.link(1, peer) {
                let _ = l.rate_from(1);
            }
        }
    }
    let _ = decode::<Control>(data);
    let _ = decode::<WorldInfo>(data);
    if let Ok(t) = decode::<TruthMap>(data) {
        let _ = Grid::from_rle(&t.grid_rle);
        let _ = Grid::from_rle(&t.reachable_rle);
    }
    let _ = decode::<LinkReport>(data);
    if let Ok(h) = decode::<proto::msg::Held>(data) {
        let _ = h.owners.iter().map(|o| proto::msg::owner_life(o.owner)).count();
    }
    if let Ok(o) = decode::<ProcessOrder>(data) {
        let mut s = Scenario::default();
        s.robots.count = 3;
        let _ = s.check_process_action(&o.into());
    }
    let _ = Grid::from_rle(data);
}


const STRATEGIES: [Strategy; 6] = [
    Strategy::Decentralized,
    Strategy::Burgard,
    Strategy::Uncoordinated,
    Strategy::Bids,
    Strategy::Roles,
    Strategy::Pack,
];

const MODES: [ExchangeMode; 3] = [
    ExchangeMode::Polygon,
    ExchangeMode::RawScans,
    ExchangeMode::GridSnapshots,
];

/// Radio payloads: the first byte picks the kind, the second the strategy (bits 0–2), the
/// exchange mode (bits 3–4) and whether the robot acts on what it took (bit 7); the rest is the
/// payload, received by a new robot. What decodes is taken; with bit 7 set the robot then
/// integrates a scan, plans and sends on what it was told. (A step costs about ten times the
/// taking, so the fuzzer decides per input how deep to go, and the long run still gets through
/// its ten million inputs.)
pub fn radio(data: &[u8]) {
    let [k, c, payload @ ..] = data else {
        return;
    };
    let kind = RADIO_KINDS[usize::from(*k) % RADIO_KINDS.len()];
    let strategy = STRATEGIES[usize::from(*c & 7) % STRATEGIES.len()];
    let mode = MODES[usize::from((*c >> 3) & 3) % MODES.len()];
    let mut a = agent(strategy, mode);
    let msgs = a.receive(kind, payload).msgs;
    let took = !msgs.is_empty();
    for m in msgs {
        let _ = a.take(m);
    }
    if took && *c & 0x80 != 0 {
        let _ = a.on_scan(&plain_scan(1));
        let _ = a.radio_step();
        let _ = a.frames();
    }
}

/// The compact op encoding: decoded, re-encoded, and applied op by op to a replica.
pub fn op_chunk(data: &[u8]) {
    let Ok(ops) = robot_agent::exchange::wire::decode(data) else {
        return;
    };
    let _ = robot_agent::exchange::wire::encode(&ops);
    let mut replica = robot_agent::exchange::oplog::Replica::new();
    for op in &ops {
        if replica.apply(op).is_err() {
            replica.rewind();
        }
    }
    let _ = replica.committed().digest();
}

/// Scenario TOML: the whole input as a scenario file; each of its first lines as a `--set`
/// override of the default scenario; the faults of what loads.
pub fn scenario(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let mut loaded = Vec::new();
    if let Ok(s) = Scenario::from_toml(text, &[]) {
        loaded.push(s);
    }
    let sets: Vec<String> = text.lines().take(4).map(str::to_string).collect();
    if let Ok(s) = Scenario::from_toml("", &sets) {
        loaded.push(s);
    }
    for s in loaded {
        let _ = s.process_faults();
        let _ = netem::faults::parse_faults(&s.faults);
        let _ = s.to_toml();
    }
}

/// ROS map_server YAML (relative image paths resolve against a directory that does not exist,
/// so no file is read).
pub fn map_yaml(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = world_server::map::parse_map_yaml(text, Path::new("/nonexistent/swarm-fuzz/map.yaml"));
    }
}

/// Map images (PGM, PNG) under each interpretation mode.
pub fn map_image(data: &[u8]) {
    use world_server::image::{decode as decode_image, Mode, Thresholds};
    let mode = match data.first().map(|b| b % 3) {
        Some(1) => Mode::Scale,
        Some(2) => Mode::Raw,
        _ => Mode::Trinary,
    };
    let t = Thresholds {
        negate: data.len() % 2 == 1,
        occupied_thresh: 0.65,
        free_thresh: 0.196,
        mode,
    };
    let _ = decode_image(data, &t);
}

/// netem's control API: a request body.
pub fn netem_http(data: &[u8]) {
    netem::http::decode_only(data);
}

/// Every target by name, for [`smoke`].
pub const TARGETS: [(&str, fn(&[u8])); 7] = [
    ("sim_plane", sim_plane),
    ("radio", radio),
    ("op_chunk", op_chunk),
    ("scenario", scenario),
    ("map_yaml", map_yaml),
    ("map_image", map_image),
    ("netem_http", netem_http),
];

/// The corpus of `target`: every file in `corpus/<target>/`.
pub fn corpus(target: &str) -> Vec<Vec<u8>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("corpus").join(target);
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    files.sort();
    files.iter().filter_map(|p| std::fs::read(p).ok()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// `runs` inputs for `f`: its corpus, then seeded mutations of it — bytes flipped,
    /// inserted, deleted, inputs cut and spliced (a bounded, uninstrumented cousin of
    /// libFuzzer's run).
    fn smoke(name: &str, f: fn(&[u8]), runs: usize) {
        let corpus = corpus(name);
        assert!(!corpus.is_empty(), "corpus/{name}/ is empty");
        for input in &corpus {
            f(input);
        }
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        for _ in 0..runs {
            let mut input = corpus[rng.gen_range(0..corpus.len())].clone();
            for _ in 0..rng.gen_range(1..8) {
                let at = rng.gen_range(0..=input.len());
                match rng.gen_range(0..5) {
                    0 if at < input.len() => input[at] ^= 1 << rng.gen_range(0..8),
                    1 => input.insert(at, rng.gen()),
                    2 if at < input.len() => {
                        input.remove(at);
                    }
                    3 => input.truncate(at),
                    _ => {
                        let other = &corpus[rng.gen_range(0..corpus.len())];
                        let from = rng.gen_range(0..=other.len());
                        input.splice(at..at, other[from..].iter().copied().take(64));
                    }
                }
            }
            f(&input);
        }
    }

    fn write(target: &str, name: &str, bytes: &[u8]) {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("corpus").join(target);
        std::fs::create_dir_all(&dir).expect("corpus dir");
        std::fs::write(dir.join(name), bytes).expect("corpus file");
    }

    /// Writes the seed corpora: `cargo test --release --manifest-path fuzz/Cargo.toml --
    /// --ignored write_seed_corpus`.
    #[test]
    #[ignore]
    fn write_seed_corpus() {
        use proto::msg::{encode, LinkAir, LinkCut, LinkState, NodeAir, OpChunk, PlannedLink, RobotStatus};
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        // Radio: three robots of each strategy and exchange mode talking for a few steps.
        let mut seen = std::collections::BTreeSet::new();
        let mut ops_chunks = 0;
        for (si, &strategy) in STRATEGIES.iter().enumerate() {
            for (mi, &mode) in MODES.iter().enumerate() {
                let mut s = Scenario::default();
                s.robots.count = 3;
                s.coordination.strategy = strategy;
                s.exchange.mode = mode;
                s.base_station.enabled = matches!(strategy, Strategy::Bids | Strategy::Roles);
                let n = s.nodes();
                let mut team: Vec<Agent> = (0..n).map(|i| Agent::new(i, world(n), &s)).collect();
                let mut out = Vec::new();
                for (i, a) in team.iter_mut().enumerate() {
                    let others: Vec<u16> = (0..n).filter(|&j| usize::from(j) != i).collect();
                    out.extend(a.set_neighbours(&others).0);
                }
                for step in 0..6 {
                    for (i, a) in team.iter_mut().enumerate() {
                        let mut scan = plain_scan(step);
                        scan.pose.x = 1.5 + i as f64;
                        let _ = a.on_scan(&scan);
                        out.extend(a.radio_step());
                        out.extend(a.frames());
                    }
                    for o in std::mem::take(&mut out) {
                        let kind = proto::keys::radio_kind(&o.key).unwrap_or_default().to_string();
                        // A frame, and each message it carries, as if sent alone.
                        let mut payloads = vec![(kind.clone(), o.bytes.clone())];
                        if let Ok(f) = decode::<proto::msg::Frame>(&o.bytes) {
                            for (k, b) in f.records {
                                let Some(k) = RADIO_KINDS.get(usize::from(k)) else {
                                    continue;
                                };
                                payloads.push((k.to_string(), b));
                            }
                        }
                        for (kind, bytes) in payloads {
                            let Some(k) = RADIO_KINDS.iter().position(|&r| r == kind) else {
                                continue;
                            };
                            if kind == "ops" && ops_chunks < 12 {
                                if let Ok(c) = decode::<OpChunk>(&bytes) {
                                    write("op_chunk", &format!("chunk-{ops_chunks}"), &c.ops);
                                    ops_chunks += 1;
                                }
                            }
                            // Every seed has the robot act on what it took (bit 7).
                            let select = 0x80 | u8::try_from(si + 8 * mi).unwrap_or(0);
                            if bytes.len() < 4000 && seen.insert((kind.clone(), si, mi)) {
                                let mut input = vec![k as u8, select];
                                input.extend(&bytes);
                                write("radio", &format!("{kind}-{si}-{mi}"), &input);
                            }
                        }
                        if let Some(to) = team.get_mut(usize::from(o.to)) {
                            out.extend(to.on_radio(&kind, &o.bytes));
                        }
                    }
                }
                if si == 0 && mi == 0 {
                    let t = team[1].telemetry();
                    write("sim_plane", "telemetry", &encode(&t));
                    write("sim_plane", "held", &encode(&team[1].held()));
                }
            }
        }
        // Sim plane.
        let r = |id| RobotStatus {
            id,
            pose: Pose { x: 1.0, y: 2.0, theta: 0.5 },
            alive: true,
            distance_m: 3.0,
        };
        write(
            "sim_plane",
            "status",
            &encode(&Status { step: 4, robots: vec![r(0), r(1)], collisions_total: 1, blocked_total: 3, base: Some(r(2)), missed: vec![1] }),
        );
        write("sim_plane", "scan", &encode(&plain_scan(3)));
        write("sim_plane", "cmd", &encode(&Cmd { step: 3, robot: 1, waypoint: Some(proto::geom::Metres::new(2.0, 2.5)) }));
        write("sim_plane", "control", &encode(&Control::Stop));
        write("sim_plane", "control-pause", &encode(&Control::Pause));
        let order = ProcessOrder {
            process: proto::scenario::Process::Robot(1),
            order: proto::msg::Order::Kill { restart_after: Some(3) },
        };
        write("sim_plane", "process-order", &encode(&order));
        write("sim_plane", "world-info", &encode(&world(3)));
        let link = PlannedLink { a: 0, b: 1, rate: [Some(1000), None], delay: [1, 0], held: false, credit: [Some(8000), None], proxy: Some(([127, 0, 0, 1], 40000).into()) };
        write("sim_plane", "link-plan", &encode(&LinkPlan { step: 5, links: vec![link] }));
        let g = Grid::new(8, 6, proto::grid::Occ::Free);
        write(
            "sim_plane",
            "truth",
            &encode(&TruthMap { map: MapInfo::at_origin(8, 6, 0.1), grid_rle: g.to_rle(), reachable_rle: g.to_rle() }),
        );
        let state = LinkState {
            a: 0,
            b: 1,
            up: true,
            distance_m: Some(3.0),
            bytes_a_to_b: 10,
            bytes_b_to_a: 20,
            bytes_total: 30,
            queued_bytes: 0,
            connected: true,
            cut: None,
            air: Some(LinkAir { share: [Some(100), Some(60)], airtime: [80, 0], lost: [false, true], delivery: [0.9, 0.9] }),
        };
        let cut = LinkState { a: 0, b: 2, up: false, connected: false, cut: Some(LinkCut::Fault), ..state.clone() };
        write("sim_plane", "link-report", &encode(&LinkReport {
                step: 5,
                links: vec![state, cut],
                nodes: vec![NodeAir { id: 0, share: 100, airtime: 120, utilisation: 0.3, frames_lost: 1, retransmitted: 20 }],
            }));
        // Scenarios: the embedded default and every shipped scenario, plus faults of each kind.
        write("scenario", "default.toml", &std::fs::read(root.join("configs/default.toml")).expect("default.toml"));
        for e in std::fs::read_dir(root.join("configs/scenarios")).expect("configs/scenarios").flatten() {
            write("scenario", &e.file_name().to_string_lossy(), &std::fs::read(e.path()).expect("scenario"));
        }
        write(
            "scenario",
            "faults.toml",
            b"[robots]\ncount = 4\n[[faults]]\nstep = 3\nkind = \"kill\"\nprocess = \"robot-1\"\nrestart_after = 2\n\
              [[faults]]\nstep = 4\nkind = \"partition\"\ngroups = [[0, 1], [2, 3]]\n[[faults]]\nstep = 5\n\
              kind = \"set_toxic\"\npair = [0, 1]\ntoxic = { name = \"l\", type = \"latency\", stream = \"both\", \
              attributes = { latency = 200 } }\n[[faults]]\nstep = 6\nkind = \"freeze\"\nprocess = \"robot-2\"\n",
        );
        write("scenario", "sets.txt", b"robots.count=8\nworld.map=office\nradio.model=\"pathloss\"\nsupervise.restart=[]\n");
        // Map YAML: every shipped map's.
        for e in std::fs::read_dir(root.join("configs/maps")).expect("configs/maps").flatten() {
            if e.path().extension().is_some_and(|x| x == "yaml") {
                write("map_yaml", &e.file_name().to_string_lossy(), &std::fs::read(e.path()).expect("yaml"));
            }
        }
        // Map images: small PGMs (binary and ASCII); PNGs are committed from the maps' own.
        let mut p5 = b"P5\n# a comment\n4 3\n255\n".to_vec();
        p5.extend([0, 254, 205, 255, 0, 0, 254, 254, 205, 205, 0, 254]);
        write("map_image", "small-p5.pgm", &p5);
        write("map_image", "small-p2.pgm", b"P2\n3 2\n255\n0 254 205\n254 0 100\n");
        // netem's API: request bodies (HTTP itself is hyper's).
        for (name, body) in [
            ("cut", r#"{"enabled":false}"#),
            (
                "toxic",
                r#"{"name":"lat","type":"latency","stream":"downstream","toxicity":1.0,"attributes":{"latency":200,"jitter":20}}"#,
            ),
            ("patch", r#"{"attributes":{"rate":500}}"#),
            (
                "slicer",
                r#"{"name":"s","type":"slicer","stream":"upstream","attributes":{"average_size":16,"size_variation":4,"delay":10}}"#,
            ),
            ("slow_close", r#"{"type":"slow_close","attributes":{"delay":1500}}"#),
            (
                "update",
                r#"{"name":"r0-r1","listen":"127.0.0.1:4000","upstream":"127.0.0.1:4001","enabled":false}"#,
            ),
            ("kill", r#"{"kind":"kill","restart_after":3}"#),
            ("empty", ""),
        ] {
            write("netem_http", name, body.as_bytes());
        }
    }

    #[test]
    fn every_target_survives_its_corpus_and_random_mutations_of_it() {
        for (name, f) in TARGETS {
            smoke(name, f, 3000);
        }
    }
}
