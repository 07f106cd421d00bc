//! Whole runs complete: 1, 3 and 8 robots on small maps, within a step bound.

use std::time::Duration;

use proto::exit::ExitReason;
use swarm::rundir::summary::Summary;

use crate::support::{stderr, summary_typed, swarm_run, TempDir};

/// Runs a small scenario and checks it completes within `max_steps`.
fn completes(name: &str, sets: &[&str], max_steps: u32) -> Summary {
    let dir = TempDir::new(name);
    let steps = format!("max_steps={max_steps}");
    let mut all: Vec<&str> = sets.to_vec();
    all.push(&steps);
    // Tests run side by side on two cores: a robot may be slow, but it is not dead.
    all.push("clock.step_timeout_ms=10000");
    let (out, run) = swarm_run(&dir, None, &all, Duration::from_secs(300));
    let s = summary_typed(&run);
    assert!(
        out.status.success(),
        "{name}: swarm run failed: {}\nsummary: {s:?}",
        stderr(&out)
    );
    assert!(s.complete, "{name}: {s:?}");
    assert_eq!(s.exit_reason, ExitReason::Explored, "{name}: {s:?}");
    let steps = s.exploration_steps.expect("exploration_steps is set");
    assert!(steps <= max_steps, "{name}: {steps} steps");
    for f in [
        "scenario.toml",
        "metrics.csv",
        "truth.png",
        "robot_0.png",
        "logs/world-server.log",
    ] {
        assert!(run.join(f).is_file(), "{name}: {f} is written");
    }
    s
}

#[test]
fn one_robot_explores_a_small_office() {
    completes(
        "one",
        &[
            "world.map=office",
            "world.width_m=14",
            "world.height_m=10",
            "robots.count=1",
        ],
        600,
    );
}

#[test]
fn three_robots_explore_a_small_office_and_share_scans() {
    let s = completes(
        "three",
        &[
            "world.map=office",
            "world.width_m=14",
            "world.height_m=10",
            "robots.count=3",
            "seed=3",
            "exchange.mode=raw-scans",
        ],
        400,
    );
    assert!(s.bytes_payload_total > 0, "robots exchanged scans: {s:?}");
    assert!(s.bytes_by_type["scan"] > 0, "{s:?}");
    assert!(s.bytes_by_type["conn"] > 0, "{s:?}");
}

/// The second baseline: robots share the cells each scan changed (`grid-snapshots`).
#[test]
fn three_robots_explore_a_small_office_sharing_grid_patches() {
    let s = completes(
        "patches",
        &[
            "world.map=office",
            "world.width_m=14",
            "world.height_m=10",
            "robots.count=3",
            "seed=3",
            "exchange.mode=grid-snapshots",
        ],
        400,
    );
    let by = &s.bytes_by_type;
    assert!(by["cells"] > 0, "{s:?}");
    assert_eq!(by["scan"], 0, "{s:?}");
    assert_eq!(by["ins"], 0, "{s:?}");
    assert_eq!(s.radio_decode_errors, 0, "{s:?}");
}

/// Burgard et al.'s team assignment over the radio: the sub-team tables travel (as `targ`).
#[test]
fn three_robots_coordinated_by_burgard_assignment_explore_a_small_office() {
    let s = completes(
        "burgard",
        &[
            "world.map=office",
            "world.width_m=14",
            "world.height_m=10",
            "robots.count=3",
            "seed=3",
            "coordination.strategy=burgard",
        ],
        400,
    );
    assert!(s.bytes_by_type["targ"] > 0, "{s:?}");
}

#[test]
fn eight_robots_explore_a_small_real_map() {
    completes("eight", &["world.map=fr101", "robots.count=8"], 400);
}

/// The maps that trip a robot's notion of what it can reach are explored completely by 5 robots
/// at 1 kB/s, 10 m range, polygon exchange: raw SLAM output with laser-ray streaks and
/// single-cell holes (`intel_gmapping_raw`), and one-cell doors, zigzags, staircases and streaks
/// (`narrow_gaps`) — see tests/fixtures/maps/SOURCES.md.
#[test]
fn maps_with_ray_streaks_and_narrow_gaps_are_explored_completely() {
    let fixture = |name: &str| {
        let yaml = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/maps")
            .join(name);
        format!("world.map={}", yaml.display())
    };
    for (name, max_steps) in [("narrow_gaps.yaml", 400), ("intel_gmapping_raw.yaml", 900)] {
        let map = fixture(name);
        let sets = [
            map.as_str(),
            "robots.count=5",
            "radio.model=disk",
            "radio.range_m=10",
        ];
        let s = completes(name, &sets, max_steps);
        assert_eq!(s.robots, 5, "{name}");
    }
}
