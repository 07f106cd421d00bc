//! Process faults scheduled in the scenario (`[[faults]]` of kind `kill`, `restart`, `freeze`,
//! `thaw`), each in a real run of five robots on intel_lab: a robot killed and started again
//! rejoins in its next life and gets its first life's log back from its peers; netem restarted
//! mid-run; a robot frozen, declared dead, thawed and back; the world-server killed. And the
//! same faults asked for at runtime through netem's API (`swarm netem kill|freeze|thaw`).

use std::collections::HashMap;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

use proto::exit::ExitReason;
use swarm::process::supervise::EventKind;
use swarm::rundir::summary::{LostLog, Summary};

use crate::support::{
    csv, num, run_args, stderr, summary_typed, swarm_run, wait_file, wait_steps, Launcher, TempDir,
    SWARM,
};

/// A 5-robot intel_lab run (the embedded default scenario) with `faults` appended.
fn run_with(
    name: &str,
    faults: &str,
    sets: &[&str],
) -> (TempDir, std::process::Output, std::path::PathBuf) {
    let dir = TempDir::new(name);
    let scenario = dir.path().join("faults.toml");
    std::fs::write(&scenario, format!("[robots]\ncount = 5\n{faults}")).expect("write scenario");
    let (out, run) = swarm_run(&dir, scenario.to_str(), sets, Duration::from_secs(300));
    (dir, out, run)
}

fn events(s: &Summary) -> Vec<(u32, String, EventKind)> {
    s.process_events
        .iter()
        .map(|e| (e.step, e.process.to_string(), e.event))
        .collect()
}

#[test]
fn a_robot_killed_and_started_again_rejoins_with_its_first_life_held_by_the_team() {
    let (_dir, out, run) = run_with(
        "kill-robot",
        "[[faults]]\nstep = 30\nkind = \"kill\"\nprocess = \"robot-2\"\nrestart_after = 3\n",
        &[],
    );
    let s = summary_typed(&run);
    assert_eq!(out.status.code(), Some(0), "{}\n{s:?}", stderr(&out));
    assert!(s.complete, "{s:?}");
    assert_eq!(s.robots_alive_at_end, 5, "{s:?}");
    assert_eq!(
        events(&s),
        vec![
            (30, "robot-2".into(), EventKind::Killed),
            (33, "robot-2".into(), EventKind::Started)
        ]
    );
    // Its first life's log (owner 2) against what the team holds at the end.
    let [LostLog {
        robot: 2,
        life: 0,
        ops_written: written,
        ops_held: held,
        ops_lost: lost,
        ..
    }] = s.lost_logs[..]
    else {
        panic!("one lost log, robot 2's first life: {:?}", s.lost_logs);
    };
    assert!(written > 0, "{s:?}");
    assert_eq!(lost, written - held, "{s:?}");
    // The restarted robot took its first life back from its peers, and writes its second
    // life's log (owner 2 + 1024), which the others hold too. (A robot's entry lists the
    // owners it holds ops of.)
    let held_of = |robot: &str, owner: &str| s.logs_held.get(robot).and_then(|h| h.get(owner));
    assert_eq!(
        held_of("2", "2"),
        Some(&held),
        "robot 2 holds its first life: {s:?}"
    );
    for r in ["0", "1", "3", "4"] {
        assert!(
            held_of(r, "1026").is_some_and(|&n| n > 0),
            "robot {r} lacks robot 2's second life: {s:?}"
        );
    }
    // Robot 2 has no telemetry while it is dead, and has it again once it rejoined.
    let metrics = csv(&run.join("metrics.csv"));
    let steps_of_2: Vec<u64> = metrics
        .iter()
        .filter(|r| num(r, "robot") == 2.0)
        .map(|r| num(r, "step") as u64)
        .collect();
    assert!(!steps_of_2.contains(&32), "robot 2 reported while dead");
    assert!(
        steps_of_2.iter().any(|&t| t > 40),
        "robot 2 never came back"
    );
}

#[test]
fn netem_restarted_mid_run_brings_every_link_back_and_the_run_completes() {
    let (_dir, out, run) = run_with(
        "restart-netem",
        "[[faults]]\nstep = 30\nkind = \"restart\"\nprocess = \"netem\"\n",
        &[],
    );
    let s = summary_typed(&run);
    assert_eq!(out.status.code(), Some(0), "{}\n{s:?}", stderr(&out));
    assert!(s.complete, "{s:?}");
    assert!(s.failed_processes.is_empty(), "{s:?}");
    assert_eq!(
        events(&s),
        vec![
            (30, "netem".into(), EventKind::Killed),
            (30, "netem".into(), EventKind::Started)
        ]
    );
    // Within 2 steps of the new netem's first step, links are up and connected again.
    let links = csv(&run.join("links.csv"));
    let connected = |step: u64| {
        links
            .iter()
            .filter(|l| num(l, "step") as u64 == step && num(l, "connected") == 1.0)
            .count()
    };
    assert!(connected(28) > 0, "links before the restart");
    let back = (31..=40).find(|&t| connected(t) > 0);
    assert!(back.is_some_and(|t| t <= 33), "links back at {back:?}");
    // The wire total spans both of netem's lives.
    let before: f64 = links
        .iter()
        .filter(|l| num(l, "step") as u64 == 28)
        .map(|l| num(l, "bytes_total"))
        .sum();
    let wire = s.bytes_wire_total.expect("bytes_wire_total");
    assert!(wire as f64 > before, "{s:?}");
}

#[test]
fn a_frozen_robot_is_declared_dead_and_rejoins_when_thawed() {
    let (_dir, out, run) = run_with(
        "freeze",
        "[clock]\nstep_timeout_ms = 500\n\
         [[faults]]\nstep = 30\nkind = \"freeze\"\nprocess = \"robot-1\"\n\
         [[faults]]\nstep = 50\nkind = \"thaw\"\nprocess = \"robot-1\"\n",
        &[],
    );
    let s = summary_typed(&run);
    assert_eq!(out.status.code(), Some(0), "{}\n{s:?}", stderr(&out));
    assert!(s.complete, "{s:?}");
    assert_eq!(s.robots_alive_at_end, 5, "{s:?}");
    // Dead after clock.dead_after (5) missed steps: off the air and without telemetry until
    // the thaw; back after it.
    let links = csv(&run.join("links.csv"));
    let up_of_1 = |step: u64| -> usize {
        links
            .iter()
            .filter(|l| num(l, "step") as u64 == step && (num(l, "a") == 1.0 || num(l, "b") == 1.0))
            .filter(|l| num(l, "up") == 1.0)
            .count()
    };
    assert!(up_of_1(28) > 0, "robot 1 had links before");
    for t in 36..50 {
        assert_eq!(up_of_1(t), 0, "robot 1 on the air at {t} while frozen");
    }
    assert!((51..=56).any(|t| up_of_1(t) > 0), "robot 1 back on the air");
    let metrics: Vec<HashMap<String, String>> = csv(&run.join("metrics.csv"));
    let reported = |t: u64| {
        metrics
            .iter()
            .any(|r| num(r, "robot") == 1.0 && num(r, "step") as u64 == t)
    };
    assert!(!reported(40), "a frozen robot reported");
    assert!((51..=60).any(reported), "the thawed robot never reported");
}

#[test]
fn the_world_server_killed_ends_the_run_with_its_reason_and_every_file_written() {
    let (_dir, out, run) = run_with(
        "kill-world",
        "[[faults]]\nstep = 30\nkind = \"kill\"\nprocess = \"world-server\"\n",
        &[],
    );
    let s = summary_typed(&run);
    assert_eq!(out.status.code(), Some(2), "{}\n{s:?}", stderr(&out));
    assert_eq!(s.exit_reason, ExitReason::WorldServerExited, "{s:?}");
    for f in [
        "metrics.csv",
        "links.csv",
        "link_totals.csv",
        "traffic_by_type.csv",
        "truth.png",
        "robot_0.png",
        "scenario.toml",
    ] {
        assert!(run.join(f).is_file(), "{f} missing");
    }
    assert!(
        csv(&run.join("metrics.csv"))
            .iter()
            .any(|r| num(r, "step") >= 25.0),
        "metrics up to the kill"
    );
}

#[test]
fn process_faults_naming_no_process_of_the_run_are_refused_in_one_line() {
    for (faults, needle) in [
        (
            "[[faults]]\nstep = 3\nkind = \"kill\"\nprocess = \"robot-9\"\n",
            "no such process",
        ),
        (
            "[[faults]]\nstep = 3\nkind = \"restart\"\nprocess = \"world-server\"\n",
            "not restarted",
        ),
        (
            "[[faults]]\nstep = 3\nkind = \"freeze\"\nprocess = \"netem\"\n",
            "frozen",
        ),
        (
            "[[faults]]\nstep = 3\nkind = \"kill\"\nprocess = \"robot\"\n",
            "robot-<id>",
        ),
        (
            "[supervise]\nrestart = [\"world-server\"]\n",
            "supervise.restart",
        ),
    ] {
        let (_dir, out, _) = run_with("bad-fault", faults, &[]);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{faults}: {err}");
        assert!(
            err.contains(needle) && err.trim().lines().count() == 1,
            "{faults}: {err}"
        );
    }
}

/// Events of `summary.json` as (step, process, event, cause).
fn caused(s: &Summary) -> Vec<(u32, String, EventKind, String)> {
    s.process_events
        .iter()
        .map(|e| (e.step, e.process.to_string(), e.event, e.cause.clone()))
        .collect()
}

/// `swarm netem <args> --run DIR`: netem's API, with the run's token.
fn netem_cli(run: &Path, args: &[&str]) -> std::process::Output {
    Command::new(SWARM)
        .arg("netem")
        .args(args)
        .arg("--run")
        .arg(run)
        .output()
        .expect("swarm netem")
}

#[test]
fn process_faults_asked_through_netems_api_are_carried_out_at_the_next_step() {
    let dir = TempDir::new("api-faults");
    let run = dir.path().join("run");
    let mut cmd = Command::new(SWARM);
    let sets = [
        "robots.count=5",
        "clock.step_timeout_ms=500",
        "netem.api_token=true",
    ];
    run_args(&mut cmd, &run, &sets);
    let launcher = Launcher::spawn(cmd);
    wait_file(&run.join("netem.addr"), Duration::from_secs(30));
    wait_file(&run.join("netem.token"), Duration::from_secs(30));
    // Asked for as soon as the API is up: the team may not have formed its first links yet
    // (a robot frozen before its first session must not stall the others).
    let kill = netem_cli(&run, &["kill", "robot-2", "--restart-after", "3"]);
    assert!(kill.status.success(), "{}", stderr(&kill));
    let freeze = netem_cli(&run, &["freeze", "robot-1"]);
    assert!(freeze.status.success(), "{}", stderr(&freeze));
    // Not a process of this run: refused by netem, nothing done.
    let refused = netem_cli(&run, &["restart", "robot-7"]);
    assert!(!refused.status.success());
    assert!(stderr(&refused).contains("404"), "{}", stderr(&refused));
    // Robot 1 stays frozen for 3 steps of the run (each waits out its step timeout).
    wait_steps(&run, 3, Duration::from_secs(60));
    let thaw = netem_cli(&run, &["thaw", "robot-1"]);
    assert!(thaw.status.success(), "{}", stderr(&thaw));
    let out = launcher.wait_output(Duration::from_secs(300));
    let s = summary_typed(&run);
    assert_eq!(out.status.code(), Some(0), "{}\n{s:?}", stderr(&out));
    assert!(s.complete, "{s:?}");
    assert_eq!(s.robots_alive_at_end, 5, "{s:?}");
    let ev = caused(&s);
    let at = |p: &str, e: EventKind| {
        ev.iter()
            .find(|x| x.1 == p && x.2 == e)
            .map(|x| (x.0, x.3.clone()))
            .unwrap_or_else(|| panic!("no {e} of {p}: {ev:?}"))
    };
    let (killed, cause) = at("robot-2", EventKind::Killed);
    assert_eq!(cause, "api");
    assert_eq!(
        at("robot-2", EventKind::Started),
        (killed + 3, "api".to_string())
    );
    let (frozen, cause) = at("robot-1", EventKind::Frozen);
    assert_eq!(cause, "api");
    let (thawed, cause) = at("robot-1", EventKind::Thawed);
    assert_eq!(cause, "api");
    assert!(thawed > frozen, "{ev:?}");
    assert_eq!(ev.len(), 4, "nothing else done: {ev:?}");
    // Both are back: they report after their start and thaw.
    let metrics = csv(&run.join("metrics.csv"));
    for (robot, since) in [(2.0, killed + 3), (1.0, thawed)] {
        assert!(
            metrics
                .iter()
                .any(|r| num(r, "robot") == robot && num(r, "step") as u32 > since),
            "robot {robot} never reported after step {since}"
        );
    }
}
