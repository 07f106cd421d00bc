//! A run's step log and its MCAP: `swarm export-mcap` writes a file an MCAP reader opens, with a
//! message per robot report and per link step as the run's tables count them; a cut or foreign
//! run directory gives an error naming the file.

use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;
use std::time::Duration;

use crate::support::{csv, fails_naming, stderr, swarm_run, TempDir, SWARM};

#[test]
fn the_mcap_of_a_run_holds_every_report_and_link_step_of_its_tables() {
    let dir = TempDir::new("mcap");
    let (out, run) = swarm_run(
        &dir,
        None,
        &[
            "world.map=office",
            "world.width_m=14",
            "world.height_m=10",
            "robots.count=3",
            "max_steps=40",
            "clock.step_timeout_ms=10000",
        ],
        Duration::from_secs(300),
    );
    assert!(
        out.status.code().is_some_and(|c| c == 0 || c == 2),
        "{}",
        stderr(&out)
    );
    let export = Command::new(SWARM)
        .arg("export-mcap")
        .arg(&run)
        .output()
        .expect("swarm export-mcap runs");
    assert!(export.status.success(), "{}", stderr(&export));
    let bytes = std::fs::read(run.join("run.mcap")).expect("run.mcap is written");
    let mut counts: BTreeMap<String, u64> = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
        let m = m.expect("every message reads");
        serde_json::from_slice::<serde_json::Value>(&m.data).expect("JSON messages");
        *counts.entry(m.channel.topic.clone()).or_default() += 1;
    }
    let metrics = csv(&run.join("metrics.csv"));
    for robot in 0..3 {
        let rows = metrics
            .iter()
            .filter(|r| r["robot"] == robot.to_string())
            .count() as u64;
        assert!(rows > 0);
        assert_eq!(
            counts.get(&format!("/robot_{robot}/pose")),
            Some(&rows),
            "{counts:?}"
        );
        assert!(counts
            .get(&format!("/robot_{robot}/grid"))
            .is_some_and(|&n| n >= rows / 10));
    }
    let steps: BTreeSet<String> = metrics.iter().map(|r| r["step"].clone()).collect();
    assert_eq!(counts.get("/robots"), Some(&(steps.len() as u64)));
    let link_steps: BTreeSet<String> = csv(&run.join("links.csv"))
        .iter()
        .map(|r| r["step"].clone())
        .collect();
    assert!(!link_steps.is_empty());
    assert_eq!(
        counts.get("/links"),
        Some(&(link_steps.len() as u64)),
        "{counts:?}"
    );
    assert_eq!(counts.get("/links/bytes"), Some(&(link_steps.len() as u64)));
    assert_eq!(counts.get("/map/truth"), Some(&1));

    // A cut step log, and a directory that is no run.
    let log = run.join("steps.log");
    let whole = std::fs::read(&log).expect("steps.log");
    std::fs::write(&log, &whole[..whole.len() - 3]).expect("cut steps.log");
    let e = fails_naming(&["export-mcap"], &run, "steps.log");
    assert!(e.contains("cut short"), "{e}");
    fails_naming(&["export-mcap"], dir.path(), "steps.log");
}
