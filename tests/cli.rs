//! The command line: help texts and errors for bad input.

use std::process::Command;
use std::time::Duration;

use crate::support::{stderr, swarm_run, TempDir, SWARM};

fn help(args: &[&str]) -> String {
    let out = Command::new(SWARM)
        .args(args)
        .arg("--help")
        .output()
        .expect("run swarm --help");
    assert!(out.status.success(), "{args:?} --help failed");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn every_subcommand_explains_its_flags() {
    let top = help(&[]);
    for sub in ["run", "world-server", "robot-agent"] {
        assert!(top.contains(sub), "swarm --help lists {sub}");
    }
    let run = help(&["run"]);
    for flag in ["--out", "--set", "--quiet", "[SCENARIO]"] {
        assert!(
            run.contains(flag),
            "swarm run --help explains {flag}:\n{run}"
        );
    }
    let sweep = help(&["sweep"]);
    for flag in ["--slurm", "--sbatch", "--no-wait", "--collect", "job array"] {
        assert!(
            sweep.contains(flag),
            "swarm sweep --help names the Slurm mode ({flag}):\n{sweep}"
        );
    }
    assert!(
        run.contains("--hosts <FILE|slurm>") && run.contains("srun"),
        "swarm run --help names --hosts slurm:\n{run}"
    );
    let world = help(&["world-server"]);
    for flag in [
        "--scenario",
        "--set",
        "--listen",
        "--connect",
        "--config",
        "--cfg",
        "--startup-timeout-s",
    ] {
        assert!(
            world.contains(flag),
            "world-server --help explains {flag}:\n{world}"
        );
    }
    let robot = help(&["robot-agent"]);
    for flag in [
        "--id",
        "--scenario",
        "--radio-listen",
        "--radio-connect",
        "--radio-config",
        "--connect",
        "--idle-timeout-s",
    ] {
        assert!(
            robot.contains(flag),
            "robot-agent --help explains {flag}:\n{robot}"
        );
    }
}

fn run_error(args: &[&str]) -> (i32, String) {
    let dir = TempDir::new("bad");
    let out = Command::new(SWARM)
        .arg("run")
        .arg("--out")
        .arg(dir.path().join("run"))
        .args(args)
        .output()
        .expect("run swarm");
    (out.status.code().unwrap_or(-1), stderr(&out))
}

#[test]
fn malformed_scenarios_give_one_line_naming_the_key() {
    let dir = TempDir::new("scenario");
    let file = dir.path().join("bad.toml");
    std::fs::write(&file, "[radio]\nrnage_m = 5\n").expect("write scenario");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["--set", "robots.count=0"], "robots.count"),
        (vec!["--set", "robots.count=many"], "robots.count"),
        (vec!["--set", "sensor.max_range_m=-1"], "sensor.max_range_m"),
        (vec!["--set", "world.map=no_such_map"], "no_such_map"),
        (vec!["--set", "clock.mode=\"sometimes\""], "sometimes"),
        (vec![file.to_str().expect("utf-8 path")], "radio.rnage_m"),
        (vec!["--set", "radio.medium=wireless"], "wireless"),
        (vec!["--set", "radio.frame_loss=1"], "radio.frame_loss"),
        (vec!["--set", "radio.fading_db=3"], "radio.fading_db"),
        (
            vec!["--set", "radio.interference_range_m=0"],
            "radio.interference_range_m",
        ),
        (
            vec![
                "--set",
                "radio.medium=airtime",
                "--set",
                "clock.mode=realtime",
            ],
            "radio.medium",
        ),
        (
            vec!["/nonexistent/scenario.toml"],
            "/nonexistent/scenario.toml",
        ),
    ];
    for (args, needle) in cases {
        let (code, err) = run_error(&args);
        assert_eq!(code, 1, "{args:?} must fail with exit code 1: {err}");
        let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
        assert_eq!(lines.len(), 1, "{args:?}: one line expected, got {err:?}");
        assert!(
            err.contains(needle),
            "{args:?}: {err:?} should name {needle}"
        );
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

#[test]
fn malformed_map_files_are_reported_not_panicked() {
    let dir = TempDir::new("badmap");
    let yaml = dir.path().join("broken.yaml");
    std::fs::write(&yaml, "image: broken.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n").expect("write yaml");
    std::fs::write(dir.path().join("broken.pgm"), b"P5\n10 10\n255\n\x00\x01").expect("write pgm");
    let (code, err) = run_error(&["--set", &format!("world.map={}", yaml.display())]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("broken.pgm"),
        "the error names the file: {err}"
    );
    assert!(!err.contains("panicked"), "{err}");
}

/// The thesis gives ranges as a share of the environment's diagonal; `swarm run` turns that into
/// metres before any process starts, for a generated world (its extent) and a map (its known
/// area), and the run directory's scenario.toml shows both.
#[test]
fn a_range_given_as_a_share_of_the_diagonal_becomes_metres() {
    let range = |map: &str| {
        let dir = TempDir::new("pct");
        let (out, run) = swarm_run(
            &dir,
            None,
            &[
                &format!("world.map={map}"),
                "radio.range_pct_of_diagonal=50",
                "max_steps=1",
            ],
            Duration::from_secs(60),
        );
        assert!(
            out.status.code().is_some_and(|c| c != 1),
            "{}",
            stderr(&out)
        );
        let text = std::fs::read_to_string(run.join("scenario.toml")).unwrap_or_default();
        let s: toml::Value = text.parse().unwrap_or_else(|e| panic!("{e}: {text}"));
        assert_eq!(s["radio"]["range_pct_of_diagonal"].as_float(), Some(50.0));
        s["radio"]["range_m"].as_float().unwrap_or(-1.0)
    };
    // The generated office is 40 m × 30 m by default: a 50 m diagonal.
    assert!((range("office") - 25.0).abs() < 1e-9);
    // The Intel lab's known area is about 28 m × 28 m (not its whole image).
    let intel = range("intel_lab");
    assert!((15.0..25.0).contains(&intel), "{intel}");
}

#[test]
fn hosts_slurm_outside_an_allocation_is_refused_before_anything_starts() {
    let dir = TempDir::new("hosts-slurm");
    let out = dir.path().join("run");
    let o = Command::new(SWARM)
        .args(["run", "--hosts", "slurm", "--out"])
        .arg(&out)
        .env_remove("SLURM_JOB_NODELIST")
        .output()
        .expect("swarm run");
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("not inside a Slurm allocation") && err.contains("salloc"),
        "{err}"
    );
    assert!(!out.exists(), "no run directory is made");
}
