//! netem in whole runs: every robot pair's link obeys the radio range, and the HTTP API (the one
//! curl and toxiproxy's clients speak) cuts and restores a link while a run goes on.

use std::collections::HashMap;
use std::process::Command;
use std::time::{Duration, Instant};

use crate::support::{
    csv, num, stderr, summary_typed, swarm_run, wait_steps, Launcher, TempDir, SWARM,
};

/// An 8-robot run with a 6 m disk range; returns its run directory (kept by `dir`).
fn ranged_run(dir: &TempDir) -> std::path::PathBuf {
    let (out, run) = swarm_run(
        dir,
        None,
        &[
            "robots.count=8",
            "world.map=office",
            "world.width_m=30",
            "world.height_m=20",
            "radio.range_m=6",
            "max_steps=400",
        ],
        Duration::from_secs(300),
    );
    assert!(
        out.status.code().is_some_and(|c| c != 1),
        "{}",
        stderr(&out)
    );
    let s = summary_typed(&run);
    assert!(
        s.bytes_wire_total.is_some_and(|b| b > 0),
        "bytes crossed netem: {s:?}"
    );
    run
}

const RANGE_M: f64 = 6.0;

/// Also: links that re-enter range reconnect within two steps.
#[test]
fn no_link_is_up_while_its_robots_are_out_of_range() {
    let dir = TempDir::new("range");
    let run = ranged_run(&dir);
    // Robot positions per step, from the evaluator's metrics.
    let mut pos: HashMap<(u64, u64), (f64, f64)> = HashMap::new();
    for r in csv(&run.join("metrics.csv")) {
        pos.insert(
            (num(&r, "step") as u64, num(&r, "robot") as u64),
            (num(&r, "x"), num(&r, "y")),
        );
    }
    let links = csv(&run.join("links.csv"));
    let (mut checked, mut down_rows) = (0, 0);
    for l in &links {
        let (step, a, b) = (
            num(l, "step") as u64,
            num(l, "a") as u64,
            num(l, "b") as u64,
        );
        if num(l, "up") != 1.0 {
            down_rows += 1;
            continue;
        }
        if let (Some(pa), Some(pb)) = (pos.get(&(step, a)), pos.get(&(step, b))) {
            let d = (pa.0 - pb.0).hypot(pa.1 - pb.1);
            assert!(
                d <= RANGE_M + 1e-6,
                "link {a}-{b} up at step {step} with the robots {d:.2} m apart"
            );
            checked += 1;
        }
    }
    assert!(
        checked > 100 && down_rows > 0,
        "checked {checked} up rows, {down_rows} down rows"
    );
    // Links that come back into range reconnect within two steps (the robots' zenoh retry
    // period is tuned for it, proto::node::radio_peer).
    let r = summary_typed(&run).reconnect;
    assert!(r.events >= 5, "too few reconnections to judge: {r:?}");
    assert!(
        r.max_steps.is_some_and(|m| m <= 2),
        "a link needed more than 2 steps to reconnect: {r:?}"
    );
}

/// The row of the step in which a link goes down may still count bytes written just before the
/// cut; every later down step must show none. (Writes race the link's kill signal, polled first,
/// in `netem::shaping::pipeline::sink`.)
#[test]
fn no_byte_crosses_a_link_that_is_down() {
    let dir = TempDir::new("down-bytes");
    let run = ranged_run(&dir);
    let mut was_up: HashMap<(u64, u64), bool> = HashMap::new();
    // The situation the test is about: steps where a link was down a whole step.
    let mut down_steps = 0;
    for l in &csv(&run.join("links.csv")) {
        let (step, a, b) = (
            num(l, "step") as u64,
            num(l, "a") as u64,
            num(l, "b") as u64,
        );
        let up = num(l, "up") == 1.0;
        let bytes = num(l, "bytes_a_to_b") + num(l, "bytes_b_to_a");
        let previous = was_up.insert((a, b), up).unwrap_or(false);
        // A write already under way when the link was cut may complete in the step of the cut.
        if !up && !previous {
            down_steps += 1;
            assert_eq!(
                bytes, 0.0,
                "bytes crossed the down link {a}-{b} at step {step}"
            );
        }
    }
    assert!(
        down_steps > 0,
        "no link was down a whole step: nothing was checked"
    );
}

fn curl(args: &[&str]) -> (bool, String) {
    let out = Command::new("curl")
        .args(["-s", "-S", "--max-time", "5"])
        .args(args)
        .output()
        .expect("curl runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

/// `netem.api_token = true`: the API answers 401 without the run's token, and with it as a
/// bearer token (curl, and `swarm netem --run`, which reads netem.token) it works.
#[test]
fn netems_api_refuses_requests_without_the_runs_token() {
    let dir = TempDir::new("token");
    let run = dir.path().join("run");
    let mut cmd = Command::new(SWARM);
    cmd.args(["run", "--quiet", "--out"]).arg(&run);
    for s in [
        "robots.count=2",
        "world.map=office",
        "world.width_m=24",
        "world.height_m=16",
        "clock.mode=realtime",
        "clock.speedup=5",
        "max_steps=2000",
        "netem.api_token=true",
    ] {
        cmd.arg("--set").arg(s);
    }
    let _l = Launcher::spawn(cmd);
    let deadline = Instant::now() + Duration::from_secs(60);
    let (addr, token) = loop {
        let addr = std::fs::read_to_string(run.join("netem.addr"));
        let token = std::fs::read_to_string(run.join("netem.token"));
        if let (Ok(a), Ok(t)) = (addr, token) {
            break (a.trim().to_string(), t.trim().to_string());
        }
        assert!(
            Instant::now() < deadline,
            "netem.addr and netem.token never appeared"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    use std::os::unix::fs::PermissionsExt;
    let mode = std::fs::metadata(run.join("netem.token")).map(|m| m.permissions().mode() & 0o777);
    assert_eq!(mode.ok(), Some(0o600), "netem.token readable by others");
    assert_eq!(token.len(), 32, "{token}");
    let code = |extra: &[&str]| {
        let url = format!("http://{addr}/proxies");
        let mut args = vec!["-o", "/dev/null", "-w", "%{http_code}"];
        args.extend(extra);
        args.push(&url);
        curl(&args).1
    };
    let deadline = Instant::now() + Duration::from_secs(30);
    while code(&[]) == "000" {
        assert!(Instant::now() < deadline, "netem's API never answered");
        std::thread::sleep(Duration::from_millis(100));
    }
    assert_eq!(code(&[]), "401");
    assert_eq!(
        code(&[
            "-H",
            "Authorization: Bearer 00000000000000000000000000000000"
        ]),
        "401"
    );
    let header = format!("Authorization: Bearer {token}");
    assert_eq!(code(&["-H", &header]), "200");
    let ctl = |args: &[&str]| {
        Command::new(SWARM)
            .arg("netem")
            .args(args)
            .output()
            .expect("swarm netem")
    };
    let with_run = ctl(&["list", "--run", &run.to_string_lossy()]);
    assert!(with_run.status.success(), "{}", stderr(&with_run));
    let without = ctl(&["list", "--api", &addr]);
    assert!(
        !without.status.success() && stderr(&without).contains("401"),
        "{}",
        stderr(&without)
    );
}

#[test]
fn curl_cuts_and_restores_a_link_during_a_run() {
    let dir = TempDir::new("curl");
    let run = dir.path().join("run");
    let mut cmd = Command::new(SWARM);
    cmd.args(["run", "--quiet", "--out"]).arg(&run);
    for s in [
        "robots.count=3",
        "world.map=office",
        "world.width_m=24",
        "world.height_m=16",
        "radio.model=always",
        "clock.mode=realtime",
        "clock.speedup=20",
        "max_steps=2000",
    ] {
        cmd.arg("--set").arg(s);
    }
    let l = Launcher::spawn(cmd);
    let deadline = Instant::now() + Duration::from_secs(60);
    let addr = loop {
        if let Ok(a) = std::fs::read_to_string(run.join("netem.addr")) {
            break a.trim().to_string();
        }
        assert!(Instant::now() < deadline, "netem.addr never appeared");
        std::thread::sleep(Duration::from_millis(100));
    };
    // The API may take a moment to come up after the address is written.
    let deadline = Instant::now() + Duration::from_secs(30);
    while !curl(&[&format!("http://{addr}/proxies")]).0 {
        assert!(Instant::now() < deadline, "netem's API never answered");
        std::thread::sleep(Duration::from_millis(100));
    }
    let (ok, body) = curl(&[
        "-X",
        "POST",
        "-d",
        "{\"enabled\": false}",
        &format!("http://{addr}/proxies/r0-r1"),
    ]);
    assert!(ok, "{body}");
    let (_, listed) = curl(&[&format!("http://{addr}/proxies/r0-r1")]);
    let v: serde_json::Value = serde_json::from_str(&listed).expect("JSON");
    assert_eq!(v["enabled"], false, "{listed}");
    // The cut holds for 20 steps of the run.
    wait_steps(&run, 20, Duration::from_secs(60));
    let (ok, body) = curl(&[
        "-X",
        "POST",
        "-d",
        "{\"enabled\": true}",
        &format!("http://{addr}/proxies/r0-r1"),
    ]);
    assert!(ok, "{body}");
    let (ok, metrics) = curl(&[&format!("http://{addr}/metrics")]);
    assert!(ok && metrics.contains("r0-r1"), "{metrics}");
    let out = l.wait_output(Duration::from_secs(300));
    let s = summary_typed(&run);
    assert!(
        s.complete,
        "the run completes after the cut and restore: {s:?}\n{}",
        stderr(&out)
    );
    let links = csv(&run.join("links.csv"));
    let down = links
        .iter()
        .filter(|r| num(r, "a") == 0.0 && num(r, "b") == 1.0 && num(r, "up") == 0.0)
        .count();
    assert!(down > 0, "the cut shows in links.csv");
}

/// The radio sessions survive a saturated slow link: two robots whose scans (1 440 beams, about
/// 2.9 kB each step) offer about 3× a 1 000 bytes/s link, in realtime at 4× speed-up, for 130
/// simulated seconds. The radio sessions' small batches (512 B: one crosses in half a simulated
/// second; zenoh's default 64 kB batch would take 16 wall seconds here, past the 10 s lease)
/// keep bytes arriving, so the zenoh session lives on its first connection; the robots' own
/// pacing (per-link credit, `robot_agent::agent`) hands the link no more than its budget, so
/// netem's queue stays a few steps long. (Without the pacing, measured: the session survives
/// too, but netem's two 64 kB buffers fill — 16 s of queue at this speed — and what they hold is
/// lost at the end.)
#[test]
fn a_link_offered_three_times_its_budget_stays_up_for_120_simulated_seconds() {
    const BEAMS: usize = 1440;
    const BUDGET: f64 = 1000.0;
    // What each robot offers per step: one scan record of BEAMS ranges (hits of a few metres).
    let record = proto::msg::ScanDelta {
        from: 0,
        owner: 0,
        start: 60,
        records: vec![proto::msg::ScanRecord {
            step: 60,
            x_mm: 12_000,
            y_mm: 9_000,
            theta_mrad: 1_000,
            ranges_cm: vec![350; BEAMS],
        }],
    };
    let offered = proto::msg::encode(&record).len() as f64;
    assert!(offered >= 2.5 * BUDGET, "offered {offered} bytes per step");

    let dir = TempDir::new("lease");
    let (out, run) = swarm_run(
        &dir,
        None,
        &[
            "robots.count=2",
            "world.map=office",
            "world.width_m=60",
            "world.height_m=40",
            "radio.model=always",
            "radio.bandwidth_bytes_per_s=1000",
            "exchange.mode=raw-scans",
            "clock.mode=realtime",
            "clock.speedup=4",
            &format!("sensor.beams={BEAMS}"),
            "max_steps=130",
        ],
        Duration::from_secs(120),
    );
    assert!(
        out.status.code().is_some_and(|c| c != 1),
        "{}",
        stderr(&out)
    );
    let links = csv(&run.join("links.csv"));
    assert!(links.len() >= 120, "{} link rows", links.len());
    // Connected from the first step to the last, on one connection: no lease expiry, no reset.
    let gaps: Vec<u64> = links
        .iter()
        .filter(|l| num(l, "connected") != 1.0)
        .map(|l| num(l, "step") as u64)
        .collect();
    assert!(gaps.len() <= 1, "steps without a connection: {gaps:?}");
    let totals = csv(&run.join("link_totals.csv"));
    assert_eq!(num(&totals[0], "established"), 1.0, "{totals:?}");
    // The link was kept full (the offer exceeds it) and netem's queue stayed within a few
    // steps of budget (bounded by the robots' pacing, far below netem's 64 kB buffers). The
    // pacers allow a burst of 4 steps each way, and `queued_bytes` is both directions: 8 steps of
    // budget, plus what wall-clock jitter adds at 4x speed-up (one CI run: 8 240 bytes).
    let steps = links.len() as f64;
    let per_step =
        (num(&totals[0], "bytes_a_to_b") + num(&totals[0], "bytes_b_to_a")) / 2.0 / steps;
    assert!(
        (0.85 * BUDGET..=1.1 * BUDGET).contains(&per_step),
        "{per_step:.0} bytes per step each way"
    );
    let max_queued = links
        .iter()
        .map(|l| num(l, "queued_bytes"))
        .fold(0.0, f64::max);
    assert!(
        max_queued <= 12.0 * BUDGET,
        "netem held up to {max_queued} bytes"
    );
}

/// Every fault type, scheduled in one 4-robot run (radio `always`, so faults are the only cause
/// of a link going down), with its effect checked in `links.csv` and `link_totals.csv`. Without
/// step markers, so that netem itself delays, stalls and paces the bytes (with markers the
/// receivers carry latency out, and robots do not send on a stalled link); the run
/// goes on to its end with every process alive. Checks skip the step in which a fault starts or
/// ends: a step's row counts what was delivered until the next step opened, after that step's
/// faults took effect.
#[test]
fn a_run_survives_every_fault_type_and_each_shows_its_effect() {
    let dir = TempDir::new("faults");
    let scenario = dir.path().join("faults.toml");
    let toxic = |step: u32, pair: &str, body: &str| {
        format!("[[faults]]\nstep = {step}\nkind = \"set_toxic\"\npair = {pair}\ntoxic = {{ {body} }}\n")
    };
    let remove = |step: u32, pair: &str, name: &str| {
        format!("[[faults]]\nstep = {step}\nkind = \"remove_toxic\"\npair = {pair}\nname = \"{name}\"\n")
    };
    let mut text = String::from(
        "max_steps = 300\n[robots]\ncount = 4\n[world]\nmap = \"office\"\nwidth_m = 40.0\nheight_m = 30.0\n\
         [clock]\nstep_timeout_ms = 10000\nmarkers = false\n[radio]\nmodel = \"always\"\nbandwidth_bytes_per_s = 1000\n\
         [[faults]]\nstep = 20\nkind = \"partition\"\ngroups = [[0, 1], [2, 3]]\n\
         [[faults]]\nstep = 60\nkind = \"heal\"\n",
    );
    text += &toxic(
        80,
        "[0, 1]",
        "name = \"bh\", type = \"timeout\", stream = \"both\", attributes = { timeout = 0 }",
    );
    text += &remove(110, "[0, 1]", "bh");
    text += &toxic(120, "[0, 2]", "name = \"slow\", type = \"bandwidth\", stream = \"both\", attributes = { rate_bytes_per_s = 200 }");
    text += &remove(170, "[0, 2]", "slow");
    text += &toxic(120, "[1, 3]", "name = \"lim\", type = \"limit_data\", stream = \"downstream\", attributes = { bytes = 2000 }");
    text += &remove(180, "[1, 3]", "lim");
    text += &toxic(
        140,
        "[2, 3]",
        "name = \"lag\", type = \"latency\", stream = \"both\", attributes = { latency = 3000 }",
    );
    text += &remove(190, "[2, 3]", "lag");
    text += &toxic(200, "[0, 3]", "name = \"bits\", type = \"corrupt\", stream = \"both\", attributes = { probability = 0.01 }");
    text += &remove(230, "[0, 3]", "bits");
    text += "[[faults]]\nstep = 240\nkind = \"reset\"\n";
    text += "[[faults]]\nstep = 250\nkind = \"cut\"\npair = [1, 2]\n[[faults]]\nstep = 270\nkind = \"restore\"\npair = [1, 2]\n";
    std::fs::write(&scenario, text).expect("write scenario");

    let (out, run) = swarm_run(&dir, scenario.to_str(), &[], Duration::from_secs(300));
    assert!(
        out.status.code().is_some_and(|c| c != 1),
        "{}",
        stderr(&out)
    );
    let s = summary_typed(&run);
    assert!(s.failed_processes.is_empty(), "{s:?}");
    assert!(s.steps >= 280, "the run ended early: {s:?}");

    let links = csv(&run.join("links.csv"));
    let row = |step: u64, a: u64, b: u64| {
        links
            .iter()
            .find(|l| {
                num(l, "step") as u64 == step && num(l, "a") as u64 == a && num(l, "b") as u64 == b
            })
            .unwrap_or_else(|| panic!("no row for step {step}, {a}-{b}"))
    };
    let bytes = |l: &HashMap<String, String>| num(l, "bytes_a_to_b") + num(l, "bytes_b_to_a");
    let up = |l: &HashMap<String, String>| num(l, "up") == 1.0;

    // partition [[0,1],[2,3]] at 20, heal at 60.
    for step in 22..59 {
        for (a, b) in [(0, 2), (0, 3), (1, 2), (1, 3)] {
            let l = row(step, a, b);
            assert!(
                !up(l) && bytes(l) == 0.0,
                "partition: {a}-{b} at {step}: {l:?}"
            );
        }
        assert!(
            up(row(step, 0, 1)) && up(row(step, 2, 3)),
            "partition cut a pair inside a group at {step}"
        );
    }
    // Back within a few steps (on a loaded machine lockstep steps can take a few ms only; the
    // bound of 2 steps is checked on longer steps in the range test).
    for (a, b) in [(0, 2), (0, 3), (1, 2), (1, 3)] {
        assert!(
            (60..=70).any(|s| num(row(s, a, b), "connected") == 1.0),
            "{a}-{b} not back after the heal"
        );
    }
    // blackhole on 0-1 from 80 to 110: up, and nothing delivered.
    for step in 82..109 {
        let l = row(step, 0, 1);
        assert!(up(l) && bytes(l) == 0.0, "blackhole: {l:?}");
    }
    assert!(
        (111..=130).any(|s| bytes(row(s, 0, 1)) > 0.0),
        "0-1 carried nothing after the blackhole"
    );
    // bandwidth 200 B/s on 0-2 from 120 to 170: the budget grants 200 bytes a step; a row counts
    // what the kernel sent in the step, so a busy receiver can shift a grant into the next row
    // (docs/guide/netem.md, "A links.csv row"). Over the window: at most the budget plus one step.
    for d in ["bytes_a_to_b", "bytes_b_to_a"] {
        let rows: Vec<f64> = (122..169).map(|s| num(row(s, 0, 2), d)).collect();
        let total: f64 = rows.iter().sum();
        assert!(
            total <= 200.0 * (rows.len() + 1) as f64 && rows.iter().all(|&b| b <= 400.0),
            "bandwidth toxic, {d}: {rows:?}"
        );
        assert!(total > 0.0, "the slow link carried nothing, {d}: {rows:?}");
    }
    // Throttled, not stalled: while netem holds more than two steps' budget for the pair (so at
    // least one direction has a full step waiting), the step's grant crosses in the row or the
    // next (a busy receiver can take it a row late: a row of 0 then one of 400 is pacing, two
    // empty rows with a backlog are a stall). The robots may have nothing to send for a while,
    // so an idle row without a backlog is no fault (measured: some runs never queue 400 bytes
    // here).
    for s in 122..168 {
        if num(row(s, 0, 2), "queued_bytes") >= 400.0 {
            let moved = |t: u64| {
                let l = row(t, 0, 2);
                num(l, "bytes_a_to_b").max(num(l, "bytes_b_to_a"))
            };
            assert!(
                moved(s) + moved(s + 1) >= 150.0,
                "the slow link stalled with a backlog at step {s}: {:?} {:?}",
                row(s, 0, 2),
                row(s + 1, 0, 2)
            );
        }
    }
    // latency 3 s on 2-3 from 140: a byte written in step 140 arrives 3 steps later at the
    // earliest, so the steps right after the toxic appeared carry nothing (bytes already past
    // the latency stage when it appeared may still reach one of them).
    let after: Vec<_> = (141..=143).map(|s| row(s, 2, 3)).collect();
    let silent = after.iter().filter(|l| bytes(l) == 0.0).count();
    assert!(silent >= 2, "latency toxic: {after:?}");
    assert!(
        (144..190).any(|s| bytes(row(s, 2, 3)) > 0.0),
        "2-3 carried nothing under latency"
    );
    // cut 1-2 from 250 to 270.
    for step in 252..269 {
        let l = row(step, 1, 2);
        assert!(!up(l) && bytes(l) == 0.0, "cut: {l:?}");
    }
    assert!(
        (270..=280).any(|s| num(row(s, 1, 2), "connected") == 1.0),
        "1-2 not back after the restore"
    );

    // limit_data on 1-3, corruption on 0-3 and the reset of every link end connections; the
    // robots reconnect (the partition and the cut also did, for their pairs).
    let totals = csv(&run.join("link_totals.csv"));
    let established = |a: f64, b: f64| {
        totals
            .iter()
            .find(|t| num(t, "a") == a && num(t, "b") == b)
            .map(|t| num(t, "established"))
            .unwrap_or(0.0)
    };
    // 0-1: first connection + reset; 2-3: first + reset; 1-3: partition + reset + limit_data.
    assert!(established(0.0, 1.0) >= 2.0, "{totals:?}");
    assert!(
        established(1.0, 3.0) >= 4.0,
        "limit_data did not close 1-3: {totals:?}"
    );
    // Flipped bits on 0-3 either break zenoh's framing (the session closes and reconnects:
    // a fourth connection after the first, the partition and the reset) or reach the robots'
    // decoders, which count and drop what they cannot decode.
    let decode_errors = s.radio_decode_errors;
    assert!(
        established(0.0, 3.0) >= 4.0 || decode_errors > 0,
        "corruption left no trace: {decode_errors} decode errors, {totals:?}"
    );
}
