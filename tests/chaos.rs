//! `swarm chaos`: a random fault campaign against a real run, and its checker — which passes a
//! run whose recovery keeps what the team held, and fails one whose recovery is broken on
//! purpose (nodes forget a restarted robot's earlier life, `SWARM_CHAOS_BROKEN_RECOVERY`).

use std::process::{Command, Output};
use std::time::Duration;

use swarm::process::supervise::EventKind;

use crate::support::{stderr, summary_typed, Launcher, TempDir, SWARM};

/// `swarm chaos` on a small office with three robots, writing into `dir`.
fn chaos(dir: &TempDir, flags: &[&str], broken: bool) -> (Output, serde_json::Value) {
    let mut cmd = Command::new(SWARM);
    cmd.arg("chaos").arg("--out").arg(dir.path().join("chaos"));
    for s in [
        "world.map=office",
        "world.width_m=24",
        "world.height_m=16",
        "robots.count=3",
        "max_steps=1500",
        "clock.step_timeout_ms=500",
    ] {
        cmd.arg("--set").arg(s);
    }
    cmd.args(flags);
    if broken {
        cmd.env("SWARM_CHAOS_BROKEN_RECOVERY", "forget-earlier-lives");
    } else {
        cmd.env_remove("SWARM_CHAOS_BROKEN_RECOVERY");
    }
    let out = Launcher::spawn(cmd).wait_output(Duration::from_secs(400));
    let report = std::fs::read_to_string(dir.path().join("chaos/chaos.json"))
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or(serde_json::Value::Null);
    (out, report)
}

fn check<'a>(report: &'a serde_json::Value, name: &str) -> &'a serde_json::Value {
    report["checks"]
        .as_array()
        .and_then(|c| c.iter().find(|c| c["name"] == name))
        .unwrap_or(&serde_json::Value::Null)
}

#[test]
fn a_random_campaign_of_process_and_link_faults_passes_the_checker() {
    let dir = TempDir::new("chaos");
    let (out, report) = chaos(
        &dir,
        &["--faults", "8", "--seed", "2", "--within", "80"],
        false,
    );
    let line = String::from_utf8_lossy(&out.stdout).to_string();
    assert_eq!(
        out.status.code(),
        Some(0),
        "{line}\n{}\n{report}",
        stderr(&out)
    );
    assert!(line.starts_with("chaos seed 2: PASS"), "{line}");
    assert_eq!(report["pass"], true, "{report}");
    assert_eq!(
        report["faults"].as_array().map(Vec::len),
        Some(8),
        "{report}"
    );
    for name in ["completes", "logs", "panics", "orphans", "memory"] {
        assert_eq!(check(&report, name)["pass"], true, "{name}: {report}");
    }
    // What the checker judged: the run's summary, typed, as `completes` quotes it.
    let s = summary_typed(&dir.path().join("chaos/run"));
    assert!(s.complete, "{s:?}");
    assert_eq!(
        check(&report, "completes")["detail"],
        format!("complete: {} after {} steps", s.exit_reason, s.steps).as_str(),
        "{report}"
    );
    // The schedule is the seed's: the same flags give the same faults (whether the run got
    // to each depends on how long it went on, which the faults' timing changes).
    let again = TempDir::new("chaos-again");
    let (_, report2) = chaos(
        &again,
        &["--faults", "8", "--seed", "2", "--within", "80"],
        false,
    );
    let schedule = |r: &serde_json::Value| -> Vec<(serde_json::Value, serde_json::Value)> {
        r["faults"]
            .as_array()
            .into_iter()
            .flatten()
            .map(|f| (f["step"].clone(), f["what"].clone()))
            .collect()
    };
    assert_eq!(schedule(&report), schedule(&report2));
    assert_eq!(schedule(&report).len(), 8);
}

#[test]
fn the_checker_fails_a_recovery_that_forgets_a_restarted_robots_first_life() {
    // Robots killed and started again; every node drops the first life of a robot it hears
    // is back. Unlimited range, so the others hold each robot's log before it is killed.
    let flags = [
        "--only",
        "kill",
        "--faults",
        "2",
        "--seed",
        "1",
        "--within",
        "40",
        "--set",
        "radio.model=always",
    ];
    let dir = TempDir::new("chaos-broken");
    let (out, report) = chaos(&dir, &flags, true);
    assert_eq!(out.status.code(), Some(2), "{}\n{report}", stderr(&out));
    let logs = check(&report, "logs");
    assert_eq!(logs["pass"], false, "{report}");
    // The faults were carried out: a robot killed and started again in its next life.
    let s = summary_typed(&dir.path().join("chaos/run"));
    assert!(
        s.process_events
            .iter()
            .any(|e| e.event == EventKind::Started && e.life > 0),
        "{:?}",
        s.process_events
    );
    assert!(
        logs["detail"]
            .as_str()
            .is_some_and(|d| d.contains("and holds")),
        "{report}"
    );
    // The same campaign with recovery as built passes.
    let dir = TempDir::new("chaos-sound");
    let (out, report) = chaos(&dir, &flags, false);
    assert_eq!(out.status.code(), Some(0), "{}\n{report}", stderr(&out));
    assert_eq!(check(&report, "logs")["pass"], true, "{report}");
}
