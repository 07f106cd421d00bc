//! No process of a run survives it: not after a normal end, not after a robot is killed with
//! SIGKILL mid-run (the launcher reports it and the others finish), not after the launcher
//! itself is killed.

use std::process::Command;
use std::time::Duration;

use proto::exit::ExitReason;

use crate::support::{
    descendants, kill, poll, running, stderr, summary_typed, wait_for_step, wait_steps, Launcher,
    TempDir, SWARM,
};

/// Starts a run in realtime mode (200 ms per step): about 60 steps, some 12 s. The kills below
/// land at a step of the run (its `steps.log`, [`wait_for_step`]), a few steps in, whatever
/// the machine's load.
fn start(dir: &TempDir, robots: u32, sets: &[&str]) -> Launcher {
    let mut cmd = Command::new(SWARM);
    cmd.args(["run", "--quiet", "--out"])
        .arg(dir.path().join("run"));
    for s in [
        "world.map=office".to_string(),
        "world.width_m=24".into(),
        "world.height_m=16".into(),
        format!("robots.count={robots}"),
        "max_steps=1500".into(),
        "clock.mode=realtime".into(),
        "clock.speedup=5".into(),
    ]
    .into_iter()
    .chain(sets.iter().map(|s| s.to_string()))
    {
        cmd.arg("--set").arg(s);
    }
    Launcher::spawn(cmd)
}

/// Waits until the launcher has `n` live child processes (world-server + robots).
fn wait_for_children(l: &Launcher, n: usize) -> Vec<u32> {
    poll(Duration::from_secs(60), Duration::from_millis(100), || {
        let kids: Vec<u32> = descendants(l.pid)
            .into_iter()
            .filter(|&p| running(p))
            .collect();
        if kids.len() >= n {
            Ok(kids)
        } else {
            Err(format!("children did not start: {kids:?}"))
        }
    })
}

fn wait_gone(pids: &[u32]) {
    poll(Duration::from_secs(10), Duration::from_millis(100), || {
        let left: Vec<&u32> = pids.iter().filter(|&&p| running(p)).collect();
        left.is_empty()
            .then_some(())
            .ok_or_else(|| format!("processes survived: {left:?}"))
    })
}

/// Without supervision (`supervise.restart = []`) a robot killed from outside stays dead.
#[test]
fn a_robot_killed_mid_run_is_reported_and_nothing_is_left() {
    let dir = TempDir::new("kill-robot");
    let l = start(&dir, 3, &["supervise.restart=[]"]);
    let kids = wait_for_children(&l, 4);
    // Let the run get going, then kill one robot-agent process (not the world-server).
    wait_for_step(&dir.path().join("run"), 10, Duration::from_secs(60));
    let robot = kids
        .iter()
        .copied()
        .find(|&p| {
            std::fs::read_to_string(format!("/proc/{p}/cmdline"))
                .is_ok_and(|c| c.contains("robot-agent"))
        })
        .expect("a robot-agent child");
    kill(robot, 9);
    let out = l.wait_output(Duration::from_secs(300));
    let err = stderr(&out);
    assert!(
        err.contains("SIGKILL"),
        "the launcher reports the killed robot: {err}"
    );
    let s = summary_typed(&dir.path().join("run"));
    assert_eq!(s.failed_processes.len(), 1, "{s:?}");
    assert!(s.complete, "the other robots finish the exploration: {s:?}");
    assert_eq!(s.robots_alive_at_end, 2, "{s:?}");
    wait_gone(&kids);
}

#[test]
fn killing_the_launcher_takes_every_child_with_it() {
    let dir = TempDir::new("kill-launcher");
    let l = start(&dir, 2, &[]);
    let kids = wait_for_children(&l, 3);
    kill(l.pid, 9);
    wait_gone(&kids);
}

#[test]
fn a_normal_run_leaves_no_process_behind() {
    let dir = TempDir::new("normal");
    let l = start(&dir, 2, &[]);
    let kids = wait_for_children(&l, 3);
    let out = l.wait_output(Duration::from_secs(300));
    assert!(out.status.code().is_some(), "launcher exited normally");
    wait_gone(&kids);
    // processes.csv holds each process's peaks as sampled from /proc while it ran.
    let rows: Vec<swarm::process::children::ProcessRow> =
        swarm::rundir::tables::read_rows(&dir.path().join("run/processes.csv"))
            .expect("processes.csv");
    assert_eq!(
        rows.len(),
        4,
        "world-server, netem and two robots: {rows:?}"
    );
    for r in &rows {
        assert!(r.peak_rss_kb > 0, "{r:?}");
        // A zenoh process runs its own threads beside the main one; stdin, stdout, stderr.
        assert!(r.peak_threads > 1, "{r:?}");
        assert!(r.peak_fds >= 3, "{r:?}");
    }
}

/// Killing the world-server ends the run with `world-server-exited` (netem and the robots exit
/// after it, because its sim plane is gone; the launcher names the cause, not a consequence).
#[test]
fn killing_the_world_server_is_the_reported_cause() {
    let dir = TempDir::new("kill-world");
    let l = start(&dir, 2, &[]);
    // World-server, netem and 2 robots.
    let kids = wait_for_children(&l, 4);
    wait_for_step(&dir.path().join("run"), 8, Duration::from_secs(60));
    let world = kids
        .iter()
        .copied()
        .find(|&p| {
            std::fs::read_to_string(format!("/proc/{p}/cmdline"))
                .is_ok_and(|c| c.contains("world-server"))
        })
        .expect("a world-server child");
    kill(world, 9);
    let out = l.wait_output(Duration::from_secs(120));
    assert_eq!(
        out.status.code(),
        Some(2),
        "an incomplete run: {}",
        stderr(&out)
    );
    let s = summary_typed(&dir.path().join("run"));
    assert_eq!(s.exit_reason, ExitReason::WorldServerExited, "{s:?}");
    assert!(!s.complete, "{s:?}");
    assert!(
        s.failed_processes
            .iter()
            .any(|f| f.starts_with("world-server") && f.contains("SIGKILL")),
        "{s:?}"
    );
    wait_gone(&kids);
}

/// The pid of the running child of `launcher` whose command line contains `what`.
fn child_running(launcher: u32, what: &str) -> Option<u32> {
    descendants(launcher).into_iter().find(|&p| {
        running(p)
            && std::fs::read_to_string(format!("/proc/{p}/cmdline"))
                .is_ok_and(|c| c.replace('\0', " ").contains(what))
    })
}

/// Waits until a child matching `what` other than `not` runs.
fn wait_for_new(launcher: u32, what: &str, not: u32) -> u32 {
    poll(Duration::from_secs(30), Duration::from_millis(50), || {
        child_running(launcher, what)
            .filter(|&p| p != not)
            .ok_or_else(|| format!("{what} was not started again"))
    })
}

/// Supervision (the default `[supervise]`: robots and netem): a robot and netem killed with
/// SIGKILL from outside the run are started again; the run completes with every robot, and
/// every process of every life is gone after it.
#[test]
fn robots_and_netem_killed_from_outside_are_started_again_by_supervision() {
    let dir = TempDir::new("supervise");
    let l = start(&dir, 3, &[]);
    let run = dir.path().join("run");
    let first = wait_for_children(&l, 5);
    wait_for_step(&run, 8, Duration::from_secs(60));
    let robot = child_running(l.pid, "robot-agent --id 1").expect("robot 1");
    kill(robot, 9);
    let robot2 = wait_for_new(l.pid, "robot-agent --id 1", robot);
    wait_steps(&run, 5, Duration::from_secs(60));
    let netem = child_running(l.pid, "netem serve").expect("netem");
    kill(netem, 9);
    let netem2 = wait_for_new(l.pid, "netem serve", netem);
    let mut all = first;
    all.extend([robot2, netem2]);
    let out = l.wait_output(Duration::from_secs(300));
    let s = summary_typed(&run);
    assert!(s.complete, "{}\n{s:?}", stderr(&out));
    assert_eq!(s.robots_alive_at_end, 3, "{s:?}");
    crate::support::assert_killed_and_supervised(&s, &["robot-1", "netem"]);
    wait_gone(&all);
}

/// A launcher killed with SIGKILL mid-run (a lockstep run with a base station) leaves its tables
/// holding every step it had closed — each step whole, the contact and communication columns
/// filled in — and no `summary.json` (the run was cut); `swarm export-mcap` reads the step log
/// up to its last whole record.
#[test]
fn a_launcher_killed_mid_run_leaves_its_tables_up_to_the_steps_it_took_in() {
    use swarm::rundir::tables::{read_rows, LinkCsv, MetricsRow};
    let dir = TempDir::new("kill-launcher-tables");
    let run = dir.path().join("run");
    let mut cmd = Command::new(SWARM);
    crate::support::run_args(
        &mut cmd,
        &run,
        &[
            "world.map=office",
            "world.width_m=24",
            "world.height_m=16",
            "robots.count=3",
            "base_station.enabled=true",
            "max_steps=5000",
        ],
    );
    let l = Launcher::spawn(cmd);
    let kids = wait_for_children(&l, 5);
    let at = wait_for_step(&run, 40, Duration::from_secs(120));
    kill(l.pid, 9);
    let _ = l.wait_output(Duration::from_secs(30));
    wait_gone(&kids);
    assert!(
        !run.join("summary.json").exists(),
        "a run cut short has no summary"
    );
    let metrics: Vec<MetricsRow> =
        read_rows(&run.join("metrics.csv")).unwrap_or_else(|e| panic!("{e:#}"));
    let last = metrics
        .last()
        .map(|r| r.step)
        .expect("metrics.csv has rows");
    // netem reports a step when the next one opens: the tables may lag the world by a step or two.
    assert!(
        last + 3 >= at,
        "metrics.csv ends at step {last}, the run was at {at}"
    );
    for s in 0..=last {
        let nodes: Vec<u16> = metrics
            .iter()
            .filter(|r| r.step == s)
            .map(|r| r.robot)
            .collect();
        assert_eq!(
            nodes,
            [0, 1, 2, 3],
            "step {s} of metrics.csv is whole, by robot"
        );
    }
    for r in metrics.iter().filter(|r| r.robot != 3) {
        assert!(
            r.steps_since_base.is_some() && r.comm_level_pct.is_some(),
            "the columns that need the step's links are filled in: {r:?}"
        );
    }
    let links: Vec<LinkCsv> = read_rows(&run.join("links.csv")).unwrap_or_else(|e| panic!("{e:#}"));
    for s in 0..=last {
        assert_eq!(
            links.iter().filter(|l| l.step == s).count(),
            6,
            "step {s} of links.csv has every pair of the 4 nodes"
        );
    }
    assert!(links.iter().all(|l| l.step <= last));
    let traffic = crate::support::csv(&run.join("traffic_by_type.csv"));
    assert_eq!(
        traffic.len(),
        metrics.len(),
        "traffic_by_type.csv has every row"
    );
    let (mcap, said) = crate::support::export_mcap(&run);
    assert!(!mcap.is_empty(), "{said}");
}
