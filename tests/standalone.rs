//! The `swarm` binary on its own, with its defaults: copied into an empty directory it runs the
//! default scenario from the maps it carries (`swarm maps` lists them; an unknown map's error
//! names them, and no path of the machine it was built on); a big team needs no clock flag
//! (its step wait follows the team and the machine, `proto::step_wait`); a hung robot is still
//! found within the documented bound.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use crate::support::{stderr, summary_typed, swarm_run, Launcher, TempDir, SWARM};

/// Every map `configs/maps/` ships.
fn shipped_maps() -> Vec<String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/maps");
    let mut maps: Vec<String> = std::fs::read_dir(&dir)
        .expect("configs/maps")
        .flatten()
        .filter_map(|e| {
            let n = e.file_name().to_string_lossy().into_owned();
            n.strip_suffix(".yaml").map(String::from)
        })
        .collect();
    maps.sort();
    maps
}

#[test]
fn the_binary_alone_in_an_empty_directory_runs_the_default_and_knows_its_maps() {
    let dir = TempDir::new("alone");
    let exe = dir.path().join("swarm");
    std::fs::copy(SWARM, &exe).expect("copy the binary");
    let swarm = |args: &[&str]| {
        let mut cmd = Command::new(&exe);
        cmd.args(args).current_dir(dir.path());
        cmd
    };
    let listed = swarm(&["maps"]).output().expect("swarm maps");
    let listed = String::from_utf8_lossy(&listed.stdout).into_owned();
    for m in shipped_maps() {
        assert!(
            listed.contains(&format!("\n{m}  ")),
            "swarm maps lists {m}:\n{listed}"
        );
    }
    let o = Launcher::spawn(swarm(&["run", "--quiet"])).wait_output(Duration::from_secs(120));
    assert!(o.status.success(), "{}", stderr(&o));
    let runs: Vec<_> = std::fs::read_dir(dir.path().join("runs"))
        .expect("runs/")
        .flatten()
        .map(|e| e.path())
        .collect();
    assert_eq!(runs.len(), 1, "{runs:?}");
    let s = summary_typed(&runs[0]);
    assert!(s.complete && s.deterministic, "{s:?}");
    let o = swarm(&["run", "--set", "world.map=intel_lba"])
        .output()
        .expect("swarm run");
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    for m in shipped_maps() {
        assert!(err.contains(&m), "the error names {m}: {err}");
    }
    let tree = env!("CARGO_MANIFEST_DIR");
    for text in [&err, &listed] {
        assert!(!text.contains(tree), "a build-machine path in {text}");
    }
}

#[test]
fn sixty_four_robots_need_no_clock_flag() {
    let dir = TempDir::new("sixty-four");
    let sets = ["robots.count=64", "world.map=aces3_austin", "max_steps=50"];
    let (o, run) = swarm_run(&dir, None, &sets, Duration::from_secs(600));
    let s = summary_typed(&run);
    assert_eq!(o.status.code(), Some(2), "{}\n{s:?}", stderr(&o));
    assert_eq!(s.steps, 50, "{s:?}");
    assert!(
        s.deterministic && s.nondeterministic.is_empty(),
        "no step decided by a wall-clock wait: {:?}",
        s.nondeterministic
    );
    assert_eq!(s.robots_alive_at_end, 64, "{s:?}");
}

/// The world's log lines: (seconds of the day, text without the time).
fn world_log(run: &Path) -> Vec<(f64, String)> {
    let log = std::fs::read_to_string(run.join("logs/world-server.log")).unwrap_or_default();
    log.lines()
        .filter_map(|l| {
            // `2026-12-06T06:47:59.193977Z  WARN …`, perhaps with colour codes.
            let at = l.find('T')?;
            let hms = l.get(at + 1..at + 16)?;
            let mut parts = hms.split(':');
            let h: f64 = parts.next()?.parse().ok()?;
            let m: f64 = parts.next()?.parse().ok()?;
            let s: f64 = parts.next()?.parse().ok()?;
            Some((h * 3600.0 + m * 60.0 + s, l[at + 16..].to_string()))
        })
        .collect()
}

/// The waits the world ran out of, from its log: (when, step, wait in seconds, robots).
fn waits_run_out(run: &Path) -> Vec<(f64, u32, f64, String)> {
    world_log(run)
        .into_iter()
        .filter_map(|(at, l)| {
            let rest = l.split_once("step ")?.1;
            let (step, rest) = rest.split_once(" timed out after ")?;
            let (wait, rest) = rest.split_once(" without the commands of robots ")?;
            let secs = match wait.strip_suffix("ms") {
                Some(ms) => ms.parse::<f64>().ok()? / 1000.0,
                None => wait.strip_suffix('s')?.parse().ok()?,
            };
            Some((at, step.parse().ok()?, secs, rest.trim().to_string()))
        })
        .collect()
}

#[test]
fn a_frozen_robot_is_declared_dead_within_dead_after_step_waits_by_default() {
    let dir = TempDir::new("hung");
    let scenario = dir.path().join("hung.toml");
    std::fs::write(
        &scenario,
        "[[faults]]\nstep = 30\nkind = \"freeze\"\nprocess = \"robot-1\"\n",
    )
    .expect("write scenario");
    let (o, run) = swarm_run(&dir, scenario.to_str(), &[], Duration::from_secs(300));
    let s = summary_typed(&run);
    assert_eq!(s.robots_alive_at_end, 3, "{}\n{s:?}", stderr(&o));
    // A 4-robot team's wait is the floor, 2 s; robot 1 (and robot 0, waiting for its frames)
    // waited out in the steps from the freeze on, at most `dead_after` (5) of them.
    let waits = waits_run_out(&run);
    assert!(
        waits.iter().all(|w| (1.9..=2.1).contains(&w.2)),
        "{waits:?}"
    );
    let of_1: Vec<u32> = (waits.iter())
        .filter(|w| w.3.contains(" 1,") || w.3.contains("[1") || w.3.contains(" 1]"))
        .map(|w| w.1)
        .collect();
    assert!(
        (1..=5).contains(&of_1.len())
            && (30..=32).contains(&of_1[0])
            && of_1.windows(2).all(|p| p[1] == p[0] + 1),
        "robot 1 waited out in steps in a row from the freeze: {waits:?}"
    );
    // Declared dead (its lease, or its misses) within dead_after × 2 s of the first wait's start.
    let log = world_log(&run);
    let dead = (log.iter())
        .find(|(_, l)| l.contains("robot 1 ") && l.contains("declared dead"))
        .map(|(at, _)| *at)
        .unwrap_or_else(|| panic!("robot 1 never declared dead: {log:?}"));
    let first = waits.first().map_or(dead, |w| w.0 - w.2);
    let took = (dead - first).rem_euclid(86_400.0);
    assert!(
        took <= 5.0 * 2.0 + 1.0,
        "declared dead {took:.1} s after the freeze: {log:?}"
    );
}
