//! de Hoog et al.'s role-based exploration over the real radio (issue #15): an explorer whose
//! link to the base station never comes up gets its map to the base station through its relay,
//! and only as radio traffic that netem carried.

use std::time::Duration;

use crate::support::{csv, num, stderr, summary_typed, swarm_run, TempDir};

/// A 60 m corridor (Simmons et al.'s environment A), a relay (robot 0) and an explorer (robot 1)
/// with static roles, the path loss model with walls, and the explorer–base station link cut
/// from the first step: whatever the base station learns of the explorer's map, the relay
/// carried.
const SCENARIO: &str = "\
max_steps = 1500
[world]
map = \"corridor\"
width_m = 60.0
height_m = 12.0
[robots]
count = 2
[radio]
model = \"pathloss\"
range_m = 10.0
[coordination]
strategy = \"roles\"
[coordination.roles]
swap = false
[base_station]
enabled = true
[[faults]]
step = 0
kind = \"cut\"
pair = [1, 2]
";

#[test]
fn a_relay_carries_the_explorers_map_to_a_base_station_it_never_reached() {
    let dir = TempDir::new("roles");
    let scenario = dir.path().join("roles.toml");
    std::fs::write(&scenario, SCENARIO).expect("write scenario");
    let (out, run) = swarm_run(&dir, scenario.to_str(), &[], Duration::from_secs(400));
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let s = summary_typed(&run);
    assert!(s.complete, "{s:?}");
    assert!(s.deterministic, "{:?}", s.nondeterministic);
    // No explorer–base station link in any step; the relay's came and went.
    let links = csv(&run.join("links.csv"));
    let up = |a: &str, b: &str| {
        links
            .iter()
            .filter(|r| r["a"] == a && r["b"] == b && r["up"] == "1")
            .count()
    };
    assert_eq!(up("1", "2"), 0, "the explorer reached the base station");
    let relay_steps = up("0", "2");
    let steps = links
        .iter()
        .filter(|r| r["a"] == "0" && r["b"] == "2")
        .count();
    assert!(
        relay_steps > 0 && relay_steps < steps,
        "relay–base link up {relay_steps} of {steps} steps"
    );
    // The explorer went beyond the base station's free-space range (walls only shorten it).
    let metrics = csv(&run.join("metrics.csv"));
    let at = |robot: &str| {
        metrics
            .iter()
            .filter(move |r| r["robot"] == robot)
            .map(|r| (num(r, "x"), num(r, "y")))
            .collect::<Vec<_>>()
    };
    let base = *at("2").first().expect("base station rows");
    let farthest = at("1")
        .into_iter()
        .map(|(x, y)| (x - base.0).hypot(y - base.1))
        .fold(0.0f64, f64::max);
    assert!(
        farthest > 15.0,
        "the explorer stayed within {farthest:.1} m"
    );
    // The base station holds the explorer's own log (views.csv: holder 2, owner 1), most of it.
    let held = csv(&run.join("views.csv"))
        .iter()
        .filter(|r| r["robot"] == "2" && r["owner"] == "1")
        .map(|r| num(r, "held"))
        .fold(0.0f64, f64::max);
    let own = csv(&run.join("saves.csv"))
        .iter()
        .filter(|r| r["robot"] == "1")
        .map(|r| num(r, "log_len"))
        .fold(0.0f64, f64::max);
    assert!(
        own > 0.0 && held >= 0.5 * own,
        "base holds {held} of the explorer's {own} ops"
    );
    let awareness = s
        .awareness
        .as_ref()
        .expect("awareness, with a base station");
    let known = awareness.base_known_pct.expect("base_known_pct");
    assert!(known >= 70.0, "the base station knows {known:.1} %");
    // Roles crossed the radio as their own package type.
    let by_type = &s.bytes_by_type;
    assert!(by_type["role"] > 0, "{by_type:?}");
}
