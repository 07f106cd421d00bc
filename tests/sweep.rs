//! `swarm sweep` (issue #7, in progress): a tiny sweep of 2 grid points × 2 seeds writes one
//! `runs.csv` row per run and one `results.csv` row per point; running it again runs nothing.

use std::process::Command;
use std::time::Duration;

use crate::support::{csv, num, Launcher, TempDir, SWARM};

#[test]
fn a_tiny_sweep_writes_its_tables_and_resumes() {
    let dir = TempDir::new("sweep");
    let exp = dir.path().join("tiny.toml");
    std::fs::write(
        &exp,
        "name = \"tiny\"\nseeds = 2\n\
         set = [\"world.map=office\", \"world.width_m=14\", \"world.height_m=10\", \"robots.count=2\", \"clock.step_timeout_ms=10000\"]\n\
         [grid]\n\"exchange.mode\" = [\"raw-scans\", \"polygon\"]\n",
    )
    .expect("write experiment");
    let out = dir.path().join("out");
    // The launcher handle kills the sweep and every run it started if the test fails.
    let sweep = || {
        let mut cmd = Command::new(SWARM);
        cmd.arg("sweep")
            .arg(&exp)
            .arg("--out")
            .arg(&out)
            .arg("--jobs")
            .arg("2");
        Launcher::spawn(cmd).wait_output(Duration::from_secs(240))
    };
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
    let again = sweep();
    let said = String::from_utf8_lossy(&again.stderr).into_owned();
    assert!(
        again.status.success() && said.contains("4 already done"),
        "{said}"
    );
}
