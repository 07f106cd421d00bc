//! Lockstep runs with step markers are functions of their scenario (issue #13): the same
//! scenario and seed give the same `run_digest` — `links.csv`, `metrics.csv`,
//! `traffic_by_type.csv`, `saves.csv`, `views.csv` and every grid, byte for byte — on an idle
//! machine, under a CPU hog on every core, and beside another run, every byte still crossing
//! netem over real TCP. Checked on the default scenario and on 8 robots in the office with
//! scheduled cut/restore, partition/heal, bandwidth change, latency and a blackhole
//! (`configs/scenarios/faults.toml`), and on 8 robots sharing one radio channel in airtime over
//! lossy links and team-wide (`radio.medium`, issue #39).

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use swarm::rundir::summary::Summary;

use crate::support::{
    children_of, kill, poll, run_args, running, stderr, summary_typed, swarm_run, wait_for_step,
    Launcher, TempDir, SWARM,
};

/// The robots' tables and grids, compared file by file: the first difference, named by file and
/// line.
fn first_difference(a: &Path, b: &Path) -> Option<String> {
    let mut names: Vec<String> = (swarm::rundir::summary::DIGESTED.iter())
        .chain(&swarm::rundir::summary::DIGESTED_IF_PRESENT)
        .map(|s| s.to_string())
        .collect();
    if let Ok(rd) = std::fs::read_dir(a.join("grids")) {
        let mut g: Vec<String> = rd
            .filter_map(|e| e.ok())
            .map(|e| format!("grids/{}", e.file_name().to_string_lossy()))
            .collect();
        g.sort();
        names.extend(g);
    }
    for n in names {
        let (x, y) = (
            std::fs::read(a.join(&n)).unwrap_or_default(),
            std::fs::read(b.join(&n)).unwrap_or_default(),
        );
        if x == y {
            continue;
        }
        let (xs, ys) = (String::from_utf8_lossy(&x), String::from_utf8_lossy(&y));
        let line = xs
            .lines()
            .zip(ys.lines())
            .position(|(l, r)| l != r)
            .unwrap_or_else(|| xs.lines().count().min(ys.lines().count()));
        return Some(format!(
            "{n} differs first at line {}:\n  {}\n  {}",
            line + 1,
            xs.lines().nth(line).unwrap_or("<end>"),
            ys.lines().nth(line).unwrap_or("<end>")
        ));
    }
    None
}

/// A CPU hog on every core, killed on drop.
struct Hog(Vec<Child>);

impl Hog {
    fn start() -> Hog {
        let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
        Hog((0..cores)
            .map(|_| {
                Command::new("sh")
                    .args(["-c", "while :; do :; done"])
                    .stdout(Stdio::null())
                    .spawn()
                    .expect("start a CPU hog")
            })
            .collect())
    }
}

impl Drop for Hog {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn run_dir(out: &std::process::Output, dir: &Path) -> Summary {
    assert!(
        out.status.code().is_some_and(|c| c == 0),
        "the run failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    summary_typed(dir)
}

/// Runs `scenario` with `sets` three times — alone, under a CPU hog, beside another run — and
/// checks every digest is the first's, naming the first file and line that differs.
fn same_run_three_ways(
    name: &str,
    scenario: Option<&str>,
    sets: &[&str],
    limit: Duration,
    check: impl Fn(&Path),
) {
    let dirs: Vec<TempDir> = (0..4)
        .map(|i| TempDir::new(&format!("{name}-{i}")))
        .collect();
    let (out, alone) = swarm_run(&dirs[0], scenario, sets, limit);
    let first = run_dir(&out, &alone);
    assert!(first.deterministic, "{first:?}");
    check(&alone);
    let hogged = {
        let _hog = Hog::start();
        let (out, d) = swarm_run(&dirs[1], scenario, sets, limit * 3);
        run_dir(&out, &d);
        d
    };
    // Two at once: the second launched beside the first.
    let beside = {
        let mut cmd = Command::new(SWARM);
        cmd.arg("run")
            .arg("--quiet")
            .arg("--out")
            .arg(dirs[3].path().join("run"));
        cmd.args(scenario);
        for s in sets {
            cmd.arg("--set").arg(s);
        }
        let other = Launcher::spawn(cmd);
        let (out, d) = swarm_run(&dirs[2], scenario, sets, limit * 2);
        run_dir(&out, &d);
        let _ = other.wait_output(limit * 2);
        d
    };
    for (how, d) in [
        ("under a CPU hog", &hogged),
        ("beside another run", &beside),
    ] {
        let s = summary_typed(d);
        if let Some(diff) = first_difference(&alone, d) {
            panic!(
                "{name}: the run {how} differs from the run alone (digests {} vs {}):\n{diff}\n{s:?}",
                first.run_digest, s.run_digest
            );
        }
        assert!(s.deterministic, "{how}: {s:?}");
        assert_eq!(
            s.run_digest, first.run_digest,
            "{name} {how}: the same files, yet another digest"
        );
    }
}

#[test]
fn the_default_scenario_gives_the_same_run_alone_loaded_and_beside_another() {
    same_run_three_ways("det-default", None, &[], Duration::from_secs(180), |_| {});
}

#[test]
fn eight_robots_under_scheduled_link_faults_give_the_same_run_every_time() {
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/configs/scenarios/faults.toml");
    same_run_three_ways(
        "det-faults",
        Some(scenario),
        &[],
        Duration::from_secs(180),
        the_faults_happened,
    );
}

/// One radio channel (issue #39): 8 robots in the office sharing it in airtime, on lossy links
/// (path loss with shadowing and fading, and frames lost at random), and sharing one channel
/// team-wide (`shared`): each the same run three ways, no step left to a timeout.
#[test]
fn a_shared_channel_and_lossy_links_give_the_same_run_every_time() {
    let airtime = [
        "robots.count=8",
        "world.map=office",
        "radio.medium=airtime",
        "radio.model=pathloss",
        "radio.shadowing_db=4",
        "radio.fading_db=3",
        "radio.frame_loss=0.05",
    ];
    same_run_three_ways(
        "det-airtime",
        None,
        &airtime,
        Duration::from_secs(240),
        |run| the_channel_was_shared(run, true),
    );
    let shared = ["robots.count=8", "world.map=office", "radio.medium=shared"];
    same_run_three_ways(
        "det-shared",
        None,
        &shared,
        Duration::from_secs(240),
        |run| the_channel_was_shared(run, false),
    );
}

/// The run's channel tables are there: shares on usable links, frames lost (when `lossy`) and
/// none otherwise; no step was decided by a timeout.
fn the_channel_was_shared(run: &Path, lossy: bool) {
    let s = summary_typed(run);
    assert!(s.deterministic && s.nondeterministic.is_empty(), "{s:?}");
    let ch = s.channel.expect("summary.json's channel");
    assert!(ch.airtime_bytes > 0 && ch.utilisation_mean > 0.0, "{ch:?}");
    assert_eq!(ch.frames_lost > 0, lossy, "{ch:?}");
    let text = std::fs::read_to_string(run.join("channel_links.csv")).expect("channel_links.csv");
    let rows = text.lines().skip(1).count();
    assert!(rows > 0, "channel_links.csv has rows");
    assert!(
        text.lines()
            .skip(1)
            .all(|l| !l.split(',').nth(3).unwrap_or("").is_empty()),
        "every usable link has a share"
    );
}

/// The scheduled faults of `configs/scenarios/faults.toml` show in `links.csv`: 0–1 cut from
/// step 10 to 29, the two groups apart from 35 to 59, 0–2 up but silent from 65 to 84, and no
/// link above its rate by more than a burst while it is 300 B/s (steps 50–89).
fn the_faults_happened(run: &Path) {
    let text = std::fs::read_to_string(run.join("links.csv")).expect("links.csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).expect(name);
    let (step, a, b, up) = (col("step"), col("a"), col("b"), col("up"));
    let (ab, ba) = (col("bytes_a_to_b"), col("bytes_b_to_a"));
    let mut bw_bytes = 0u64;
    let mut seen = [false; 3];
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        let n = |i: usize| f[i].parse::<u64>().expect("a number");
        let (s, pa, pb) = (n(step), n(a), n(b));
        if (pa, pb) == (0, 1) && (10..30).contains(&s) {
            assert_eq!(f[up], "0", "0-1 is cut at step {s}: {line}");
            seen[0] = true;
        }
        if (pa < 4) != (pb < 4) && (35..60).contains(&s) {
            assert_eq!(f[up], "0", "the groups are apart at step {s}: {line}");
            seen[1] = true;
        }
        if (pa, pb) == (0, 2) && (65..85).contains(&s) && f[up] == "1" {
            assert_eq!(n(ab) + n(ba), 0, "0-2 is stalled at step {s}: {line}");
            seen[2] = true;
        }
        if (50..90).contains(&s) {
            bw_bytes = bw_bytes.max(n(ab)).max(n(ba));
        }
    }
    assert_eq!(seen, [true; 3], "every fault's steps are in links.csv");
    // 300 B/s with a 4-step burst, plus one step's handshakes after the partition heals.
    assert!(
        bw_bytes <= 2000,
        "a step carried {bw_bytes} bytes at 300 B/s"
    );
}

/// A launcher that falls behind the world at the very end — stopped (SIGSTOP) near the step
/// limit while the world-server finishes the run and exits, then let go — still takes the
/// statuses on their way and ends the run as a launcher that kept up does: the same exit
/// reason, steps and `run_digest`. (It used to judge the world-server's exit before its last
/// statuses and end the run "world-server-exited", with another digest.)
#[test]
fn a_launcher_behind_the_world_at_the_end_ends_the_run_as_one_that_kept_up() {
    let sets = ["max_steps=150"];
    let quiet_dir = TempDir::new("det-behind-quiet");
    let (quiet_out, quiet_run) = swarm_run(&quiet_dir, None, &sets, Duration::from_secs(120));
    let quiet = summary_typed(&quiet_run);

    let dir = TempDir::new("det-behind");
    let run = dir.path().join("run");
    let mut cmd = Command::new(SWARM);
    run_args(&mut cmd, &run, &sets);
    let launcher = Launcher::spawn(cmd);
    wait_for_step(&run, 100, Duration::from_secs(60));
    kill(launcher.pid, 19); // SIGSTOP
    let world = children_of(launcher.pid).into_iter().find(|&p| {
        std::fs::read_to_string(format!("/proc/{p}/cmdline"))
            .is_ok_and(|c| c.split('\0').any(|a| a == "world-server"))
    });
    // The world does not wait for the launcher: it runs to the limit and exits (a zombie until
    // the launcher, stopped, reaps it).
    let gone = world.map(|w| {
        poll(Duration::from_secs(60), Duration::from_millis(20), || {
            (!running(w))
                .then_some(())
                .ok_or_else(|| "the world-server still runs".to_string())
        })
    });
    kill(launcher.pid, 18); // SIGCONT
    assert!(gone.is_some(), "no world-server under the launcher");
    let out = launcher.wait_output(Duration::from_secs(60));
    let behind = summary_typed(&run);
    // The step limit: both runs end incomplete, with the same exit code.
    assert_eq!(
        out.status.code(),
        quiet_out.status.code(),
        "{}",
        stderr(&out)
    );
    assert_eq!(
        (behind.exit_reason, behind.steps, &behind.run_digest),
        (quiet.exit_reason, quiet.steps, &quiet.run_digest),
        "{behind:?}"
    );
}
