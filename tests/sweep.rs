//! `swarm sweep`: a tiny sweep of 2 grid points × 2 seeds writes one `runs.csv` row per run, one
//! `results.csv` row per point, its plots and curves (SVG and PNG) and `report.md`; running it
//! again runs nothing, and a directory of other settings is refused.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use crate::support::{csv, descendants, num, running, Launcher, TempDir, SWARM};

/// `swarm sweep EXP --out OUT --jobs N`.
fn sweep_cmd(exp: &Path, out: &Path, jobs: usize) -> Command {
    let mut cmd = Command::new(SWARM);
    cmd.arg("sweep")
        .arg(exp)
        .arg("--out")
        .arg(out)
        .arg("--jobs")
        .arg(jobs.to_string());
    cmd
}

#[test]
fn a_tiny_sweep_writes_its_tables_and_resumes() {
    let dir = TempDir::new("sweep");
    let exp = dir.path().join("tiny.toml");
    std::fs::write(
        &exp,
        "name = \"tiny\"\nseeds = 2\n\
         set = [\"world.map=office\", \"world.width_m=14\", \"world.height_m=10\", \"robots.count=2\", \"clock.step_timeout_ms=10000\"]\n\
         fields = [\"traffic_shares_pct.vertex\"]\n\
         [grid]\n\"exchange.mode\" = [\"raw-scans\", \"polygon\"]\n\
         [[plot]]\nname = \"time\"\ntitle = \"Exploration time\"\nx = \"exchange.mode\"\ny = \"exploration_steps\"\n\
         [[timeline]]\nname = \"channel\"\ntitle = \"Channel load\"\nseries = \"exchange.mode\"\n\
         [[curve]]\nname = \"team\"\ntitle = \"Known by the team\"\ncolumn = \"team_pct\"\nrows = \"first\"\nseries = \"exchange.mode\"\n\
         [[table]]\ntitle = \"Vertex share\"\nrows = [\"exchange.mode\"]\ncolumns = [\"traffic_shares_pct.vertex\"]\n",
    )
    .expect("write experiment");
    let out = dir.path().join("out");
    // The launcher handle kills the sweep and every run it started if the test fails.
    let sweep = || Launcher::spawn(sweep_cmd(&exp, &out, 2)).wait_output(Duration::from_secs(240));
    let first = sweep();
    let said = String::from_utf8_lossy(&first.stderr).into_owned();
    assert!(first.status.success(), "{said}");
    let runs = csv(&out.join("runs.csv"));
    assert_eq!(runs.len(), 4, "{runs:?}");
    for mode in ["raw-scans", "polygon"] {
        let mine: Vec<_> = runs.iter().filter(|r| r["exchange.mode"] == mode).collect();
        let mut seeds: Vec<f64> = mine.iter().map(|r| num(r, "seed")).collect();
        seeds.sort_by(f64::total_cmp);
        assert_eq!(seeds, [1.0, 2.0], "{mine:?}");
        assert!(
            mine.iter()
                .all(|r| r["status"] == "ok" && r["complete"] == "true"),
            "{mine:?}"
        );
    }
    let results = csv(&out.join("results.csv"));
    assert_eq!(results.len(), 2);
    for r in &results {
        let steps: Vec<f64> = runs
            .iter()
            .filter(|x| x["exchange.mode"] == r["exchange.mode"])
            .map(|x| num(x, "exploration_steps"))
            .collect();
        let mean = steps.iter().sum::<f64>() / steps.len() as f64;
        assert!(
            (num(r, "exploration_steps_mean") - mean).abs() < 1e-9,
            "{r:?}"
        );
        assert_eq!(num(r, "complete"), 2.0);
    }
    // The polygon runs have a vertex share; raw scans have none.
    for r in &runs {
        let share = r["traffic_shares_pct.vertex"].parse::<f64>();
        match r["exchange.mode"].as_str() {
            "polygon" => assert!(share.is_ok_and(|v| v > 0.0 && v <= 100.0), "{r:?}"),
            _ => assert!(share.is_err() || share == Ok(0.0), "{r:?}"),
        }
    }
    // The report embeds a chart per plot, two per timeline facet and one per curve facet, and
    // each exists as SVG and PNG.
    let report = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    let charts: Vec<&str> = report
        .lines()
        .filter_map(|l| l.strip_prefix("![").and_then(|l| l.split("](").nth(1)))
        .map(|l| l.trim_end_matches(')'))
        .collect();
    assert_eq!(charts.len(), 4, "{report}");
    for c in &charts {
        let svg = std::fs::read_to_string(out.join(c)).expect("svg");
        assert!(svg.starts_with("<svg") && svg.contains("<text"), "{c}");
        let png = std::fs::read(out.join(c.replace(".svg", ".png"))).expect("png");
        assert!(
            png.starts_with(b"\x89PNG\r\n\x1a\n") && png.len() > 5_000,
            "{c}"
        );
    }
    assert!(report.contains("| polygon | 2 |"), "{report}");
    let again = sweep();
    let said = String::from_utf8_lossy(&again.stderr).into_owned();
    assert!(
        again.status.success() && said.contains("4 already done"),
        "{said}"
    );
    // Another set of overrides in the same directory would mix runs of other settings.
    std::fs::write(
        &exp,
        std::fs::read_to_string(&exp)
            .unwrap_or_default()
            .replace("robots.count=2", "robots.count=3"),
    )
    .expect("write experiment");
    let other = sweep();
    let said = String::from_utf8_lossy(&other.stderr).into_owned();
    assert!(
        !other.status.success() && said.contains("other settings"),
        "{said}"
    );
}

/// Ctrl-C in the middle of a sweep (SIGINT to its process group, as a terminal sends it) stops
/// the sweep and every run it started; running it again keeps the finished runs and runs only
/// the missing ones.
#[test]
fn an_interrupted_sweep_runs_only_what_is_missing() {
    use std::os::unix::process::CommandExt;
    let dir = TempDir::new("sweep-int");
    let exp = dir.path().join("int.toml");
    std::fs::write(
        &exp,
        "name = \"int\"\nseeds = 2\n\
         set = [\"world.map=office\", \"world.width_m=24\", \"world.height_m=16\", \"robots.count=3\", \
         \"exchange.mode=polygon\", \"clock.step_timeout_ms=10000\"]\n\
         [grid]\n\"robots.speed_m_per_s\" = [0.4, 0.5]\n",
    )
    .expect("write experiment");
    let out = dir.path().join("out");
    let sweep = |group: bool| {
        let mut cmd = sweep_cmd(&exp, &out, 1);
        if group {
            cmd.process_group(0);
        }
        Launcher::spawn(cmd)
    };
    let finished = || -> usize {
        std::fs::read_dir(out.join("runs"))
            .map(|d| {
                d.flatten()
                    .filter(|e| {
                        // A summary being written does not read yet: not finished.
                        swarm::rundir::summary::read_summary(&e.path())
                            .is_ok_and(|s| s.exit_reason != proto::exit::ExitReason::Interrupted)
                    })
                    .count()
            })
            .unwrap_or(0)
    };
    let first = sweep(true);
    let deadline = Instant::now() + Duration::from_secs(120);
    // Interrupt once a run has finished and the next one is under way.
    let procs = loop {
        assert!(Instant::now() < deadline, "no run finished within 120 s");
        std::thread::sleep(Duration::from_millis(50));
        let procs = descendants(first.pid);
        if finished() >= 1 && procs.len() >= 3 {
            break procs;
        }
    };
    kill_group(first.pid, 2);
    let said = first.wait_output(Duration::from_secs(30));
    let kept = finished();
    assert!(
        (1..4).contains(&kept),
        "{kept} runs finished before the interrupt: {said:?}"
    );
    let deadline = Instant::now() + Duration::from_secs(10);
    while procs.iter().any(|&p| running(p)) {
        assert!(
            Instant::now() < deadline,
            "processes left after Ctrl-C: {procs:?}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let again = sweep(false).wait_output(Duration::from_secs(240));
    let said = String::from_utf8_lossy(&again.stderr).into_owned();
    assert!(
        again.status.success() && said.contains(&format!("{kept} already done")),
        "{said}"
    );
    let runs = csv(&out.join("runs.csv"));
    assert_eq!(runs.len(), 4, "{runs:?}");
    assert!(runs.iter().all(|r| r["status"] == "ok"), "{runs:?}");
}

/// Sends `sig` to the process group `pgid` (what a terminal does on Ctrl-C).
fn kill_group(pgid: u32, sig: i32) {
    let _ = Command::new("kill")
        .arg(format!("-{sig}"))
        .arg("--")
        .arg(format!("-{pgid}"))
        .status();
}
