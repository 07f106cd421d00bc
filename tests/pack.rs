//! Rooker and Birk's communicative exploration over the real radio (issue #16): a pack of five
//! keeps every robot in touch with the others in every step — by netem's links, not the pack's
//! own estimate — while nearest-frontier robots on the same world and seed drift apart; the
//! leader's moves cross netem as `move` traffic.

use std::collections::{BTreeMap, HashMap};
use std::time::Duration;

use crate::support::{csv, stderr, summary_typed, swarm_run, TempDir};

/// Simmons et al.'s `random` world (scattered obstacles, like Rooker and Birk's Fig. 4), five
/// robots, a 6 m disk radio.
const SCENARIO: &str = "\
seed = 3
max_steps = 200
[world]
map = \"random\"
width_m = 30.0
height_m = 30.0
[robots]
count = 5
[radio]
model = \"disk\"
range_m = 6.0
bandwidth_bytes_per_s = 0
";

/// Per step, the share of robot pairs (of `robots`) that links up in `links.csv` connect,
/// directly or through others, in percent.
fn levels(rows: &[HashMap<String, String>], robots: usize) -> BTreeMap<u32, f64> {
    let mut up: BTreeMap<u32, Vec<(usize, usize)>> = BTreeMap::new();
    for r in rows {
        let step: u32 = r["step"].parse().expect("step");
        let e = up.entry(step).or_default();
        if r["up"] == "1" {
            e.push((r["a"].parse().expect("a"), r["b"].parse().expect("b")));
        }
    }
    up.into_iter()
        .map(|(step, links)| {
            let mut group: Vec<usize> = (0..robots).collect();
            // Relabel until stable: every robot takes the lowest label it is linked to.
            loop {
                let before = group.clone();
                for &(a, b) in &links {
                    let m = group[a].min(group[b]);
                    group[a] = m;
                    group[b] = m;
                }
                if group == before {
                    break;
                }
            }
            let pairs = robots * (robots - 1) / 2;
            let together = (0..robots)
                .flat_map(|a| (a + 1..robots).map(move |b| (a, b)))
                .filter(|&(a, b)| group[a] == group[b])
                .count();
            (step, 100.0 * together as f64 / pairs as f64)
        })
        .collect()
}

#[test]
fn a_pack_stays_in_touch_where_nearest_frontier_robots_drift_apart() {
    let dir = TempDir::new("pack");
    let scenario = dir.path().join("pack.toml");
    std::fs::write(&scenario, SCENARIO).expect("write scenario");
    let limit = Duration::from_secs(400);

    let (out, run) = swarm_run(
        &dir,
        scenario.to_str(),
        &["coordination.strategy=\"pack\""],
        limit,
    );
    // 0: explored, 2: the step limit came first.
    assert!(matches!(out.status.code(), Some(0 | 2)), "{}", stderr(&out));
    let s = summary_typed(&run);
    assert!(s.deterministic, "{:?}", s.nondeterministic);
    let pack = levels(&csv(&run.join("links.csv")), 5);
    assert!(pack.len() >= 190, "{} steps of links", pack.len());
    let broken: Vec<(&u32, &f64)> = pack.iter().filter(|(_, &l)| l < 100.0).collect();
    assert!(broken.is_empty(), "the pack lost touch at {broken:?}");
    let level = s.comm_level_pct.expect("comm_level_pct");
    assert_eq!(level.min, 100.0, "{level:?}");
    // It explores: the team knows a good part of the world, and it moved as a pack.
    let coverage = s.best_coverage_pct;
    assert!(coverage > 35.0, "the pack explored {coverage:.1} %");
    // The leader's moves crossed the radio as their own package type.
    assert!(s.bytes_by_type["move"] > 0, "{:?}", s.bytes_by_type);
    let judged = s.link_judgement.as_ref().expect("link_judgement of pack");
    assert!(judged.judgements > 0, "{judged:?}");

    let dir = TempDir::new("pack-uncoordinated");
    let (out, run) = swarm_run(
        &dir,
        scenario.to_str(),
        &["coordination.strategy=\"uncoordinated\""],
        limit,
    );
    // 0: explored, 2: the step limit came first.
    assert!(matches!(out.status.code(), Some(0 | 2)), "{}", stderr(&out));
    let s = summary_typed(&run);
    let alone = levels(&csv(&run.join("links.csv")), 5);
    let lowest = alone.values().copied().fold(f64::INFINITY, f64::min);
    assert!(
        lowest < 50.0,
        "nearest-frontier robots kept {lowest:.0} % at least"
    );
    let level = s.comm_level_pct.expect("comm_level_pct");
    assert_eq!(level.min, lowest, "{level:?}");
    assert!(s.link_judgement.is_none(), "{:?}", s.link_judgement);
}
