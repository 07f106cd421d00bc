//! Simmons et al.'s bids and central executive over the real radio (issue #14): a base-station
//! process joins the radio plane through netem like a robot; bids reach it and assignments come
//! back only as radio traffic, counted by package type; cut off from it, robots decide alone.

use std::collections::HashMap;
use std::path::Path;
use std::time::Duration;

use crate::support::{csv, num, stderr, summary_typed, swarm_run, TempDir};

/// A small generated office, 3 robots and a base station in their spawn area, every link up
/// unless a fault cuts it (`always`), so that what the test sees is the faults' doing.
const SCENARIO: &str = "\
max_steps = 1500
[world]
map = \"office\"
width_m = 30.0
height_m = 20.0
[robots]
count = 3
[radio]
model = \"always\"
[coordination]
strategy = \"bids\"
[coordination.bids]
assignment_timeout_steps = 8
[base_station]
enabled = true
";

/// Runs `text` (+ `extra`) to its end; it must complete.
fn run(dir: &TempDir, extra: &str) -> std::path::PathBuf {
    let scenario = dir.path().join("bids.toml");
    std::fs::write(&scenario, format!("{SCENARIO}{extra}")).expect("write scenario");
    let (out, run) = swarm_run(dir, scenario.to_str(), &[], Duration::from_secs(400));
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    run
}

/// Per robot (the base station is node 3), the metrics rows by step.
fn metrics(run: &Path) -> Vec<HashMap<String, String>> {
    csv(&run.join("metrics.csv"))
}

/// Bytes of `kind` sent by `node` over the run (traffic_by_type.csv).
fn sent(run: &Path, node: u32, kind: &str) -> f64 {
    csv(&run.join("traffic_by_type.csv"))
        .iter()
        .filter(|r| r["robot"] == node.to_string())
        .map(|r| num(r, kind))
        .sum()
}

#[test]
fn bids_reach_the_base_station_and_assignments_come_back_over_netem() {
    let dir = TempDir::new("bids");
    let run = run(&dir, "");
    let s = summary_typed(&run);
    assert!(s.complete, "{s:?}");
    assert!(s.deterministic, "{:?}", s.nondeterministic);
    let by_type = &s.bytes_by_type;
    assert!(by_type["bid"] > 0, "{by_type:?}");
    assert!(by_type["task"] > 0, "{by_type:?}");
    // The base station sends tasks and never bids; each robot bids.
    assert!(sent(&run, 3, "task") > 0.0);
    assert_eq!(sent(&run, 3, "bid"), 0.0);
    for r in 0..3 {
        assert!(sent(&run, r, "bid") > 0.0, "robot {r} never bid");
    }
    // The base station's links are real links of netem: in links.csv, with bytes on them.
    let links = csv(&run.join("links.csv"));
    for r in 0..3 {
        let bytes: f64 = links
            .iter()
            .filter(|l| l["a"] == r.to_string() && l["b"] == "3")
            .map(|l| num(l, "bytes_a_to_b") + num(l, "bytes_b_to_a"))
            .sum();
        assert!(
            bytes > 0.0,
            "no bytes between robot {r} and the base station"
        );
    }
    // With every link up, robots follow assignments: after the first few steps (the first bid
    // and the executive's wait), no robot decides alone.
    let rows = metrics(&run);
    let alone: Vec<_> = rows
        .iter()
        .filter(|r| r["robot"] != "3" && num(r, "step") >= 10.0 && r["alone"] == "1")
        .map(|r| (r["step"].clone(), r["robot"].clone()))
        .collect();
    assert!(alone.is_empty(), "robots decided alone at {alone:?}");
    assert!(rows.iter().any(|r| r["robot"] == "3"), "the base reports");
}

#[test]
fn cut_off_from_the_base_robots_decide_alone_and_follow_it_again_once_it_is_back() {
    let dir = TempDir::new("bids-cut");
    let (cut, heal) = (20.0, 50.0);
    let run = run(
        &dir,
        &format!(
            "[[faults]]\nstep = {cut}\nkind = \"partition\"\ngroups = [[0, 1, 2], [3]]\n\
             [[faults]]\nstep = {heal}\nkind = \"heal\"\n"
        ),
    );
    let s = summary_typed(&run);
    assert!(s.complete, "{s:?}");
    assert!(s.deterministic, "{:?}", s.nondeterministic);
    let rows = metrics(&run);
    let robot_rows = |from: f64, to: f64| {
        rows.iter()
            .filter(move |r| r["robot"] != "3")
            .filter(move |r| (from..to).contains(&num(r, "step")))
    };
    // Before the cut they follow the executive; a timeout after it, all decide alone ...
    assert!(robot_rows(10.0, cut).all(|r| r["alone"] == "0"));
    assert!(
        robot_rows(cut + 10.0, heal).all(|r| r["alone"] == "1"),
        "robots should decide alone while the base is cut off"
    );
    // ... and once the links are back, assignments resume.
    let end = num(&rows[rows.len() - 1], "step");
    assert!(
        end > heal + 20.0,
        "the run ended at {end}, too soon to tell"
    );
    assert!(
        robot_rows(heal + 10.0, end + 1.0).all(|r| r["alone"] == "0"),
        "assignments should resume after the heal"
    );
    // Nothing crossed between the base and the robots while they were cut.
    for l in csv(&run.join("links.csv")) {
        let step = num(&l, "step");
        if l["b"] == "3" && step > cut && step < heal {
            assert_eq!(l["up"], "0", "link {}-3 up at {step}", l["a"]);
            let bytes = num(&l, "bytes_a_to_b") + num(&l, "bytes_b_to_a");
            assert_eq!(bytes, 0.0, "bytes on link {}-3 at {step}", l["a"]);
        }
    }
}
