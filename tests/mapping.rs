//! The mapping core on real maps: a full single-robot replay of intel_lab and fr079, whose mean
//! encoded bytes per op type must not exceed thesis Table 6.1 (issue #4, must-show 4).

use std::process::Command;

use crate::support::{TempDir, SWARM};

fn replay(map: &str) -> serde_json::Value {
    let dir = TempDir::new(&format!("replay-{map}"));
    let out = Command::new(SWARM)
        .args(["replay", "--set", &format!("world.map={map}"), "--out"])
        .arg(dir.path())
        .output()
        .expect("run swarm replay");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(dir.path().join("replay.json")).expect("replay.json");
    serde_json::from_str(&text).expect("replay.json is JSON")
}

#[test]
fn encoded_ops_are_no_larger_than_thesis_table_6_1() {
    for map in ["intel_lab", "fr079"] {
        let s = replay(map);
        assert!(
            s["coverage_pct"].as_f64().unwrap_or(0.0) >= 99.0,
            "{map}: the replay explores the map: {s}"
        );
        let by_type = s["by_type"].as_object().expect("by_type");
        for (name, t) in by_type {
            let thesis = t["thesis_bytes"].as_f64().expect("thesis size");
            if let Some(mean) = t["mean_bytes"].as_f64() {
                assert!(
                    mean <= thesis,
                    "{map}: {name} takes {mean} bytes on average, thesis {thesis}"
                );
            }
        }
        for common in ["ins", "rep", "del", "chg", "save"] {
            assert!(
                by_type[common]["count"].as_u64().unwrap_or(0) > 0,
                "{map}: {common} ops occur"
            );
        }
        let e = s["approx_error_avg"].as_f64().expect("e_avg");
        assert!(e > 0.0 && e < 0.5, "{map}: e_avg {e}");
    }
}
