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
