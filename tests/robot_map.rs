//! Issue #38: every grid of a run directory is a ROS `map_server` map (PGM + YAML), and a
//! robot's map from one run loads as `world.map` of the next: the new run's truth is that map,
//! cell for cell in the same frame, and its robots start on its free cells.

use std::time::Duration;

use proto::geom::Metres;
use proto::grid::Occ;

use crate::support::{csv, num, pgm, stderr, summary_typed, swarm_run, TempDir};

/// Short lockstep runs of two robots; a slow robot on a busy machine is not dead.
const SHORT: [&str; 2] = ["robots.count=2", "clock.step_timeout_ms=10000"];

#[test]
fn a_robot_s_map_from_a_run_loads_as_world_map_of_a_new_run() {
    let first_dir = TempDir::new("robot-map-1");
    let sets = [
        &SHORT[..],
        &[
            "world.map=office",
            "world.width_m=14",
            "world.height_m=10",
            "max_steps=25",
        ][..],
    ]
    .concat();
    let (out, first) = swarm_run(&first_dir, None, &sets, Duration::from_secs(120));
    // 2: the run stopped at max_steps, short of exploring the map.
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));

    // Every grid has its YAML beside it, naming it by file name.
    let grids = first.join("grids");
    let mut pgms: Vec<String> = std::fs::read_dir(&grids)
        .expect("grids/")
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".pgm"))
        .collect();
    pgms.sort();
    assert_eq!(
        pgms,
        [
            "robot_0_own.pgm",
            "robot_0_planning.pgm",
            "robot_1_own.pgm",
            "robot_1_planning.pgm",
            "truth_reachable.pgm",
        ]
    );
    for name in &pgms {
        let yaml = grids.join(name.replace(".pgm", ".yaml"));
        let text =
            std::fs::read_to_string(&yaml).unwrap_or_else(|e| panic!("{}: {e}", yaml.display()));
        assert!(text.contains(&format!("image: {name}\n")), "{text}");
        assert!(text.contains("mode: trinary\n"), "{text}");
    }

    // The second run's world is robot 0's final planning grid.
    let robot_map = grids.join("robot_0_planning.yaml");
    let second_dir = TempDir::new("robot-map-2");
    let map_set = format!("world.map={}", robot_map.display());
    let sets = [&SHORT[..], &[map_set.as_str(), "max_steps=5"][..]].concat();
    let (out, second) = swarm_run(&second_dir, None, &sets, Duration::from_secs(120));
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    let s = summary_typed(&second);
    assert_eq!(s.exit_reason, proto::exit::ExitReason::MaxSteps, "{s:?}");
    assert!(s.reachable_cells > 0, "{s:?}");
    let scenario = std::fs::read_to_string(second.join("scenario.toml")).expect("scenario.toml");
    let canonical = robot_map.canonicalize().expect("the YAML exists");
    assert!(
        scenario.contains(&format!("map = {:?}", canonical.display().to_string())),
        "{scenario}"
    );

    // Its truth, as the world-server served it (steps.log's header), is the robot's map: the
    // same frame, the same cells — read from the PGM's greys, not through our loader.
    let header = swarm::rundir::steplog::read(&second)
        .expect("steps.log")
        .header;
    let first_header = swarm::rundir::steplog::read(&first)
        .expect("steps.log")
        .header;
    assert_eq!(header.map, first_header.map, "the run's frame is kept");
    let truth = header.truth();
    let robot = pgm(&grids.join("robot_0_planning.pgm"));
    let height = robot.cells.len() / robot.width;
    assert_eq!(
        (truth.width() as usize, truth.height() as usize),
        (robot.width, height)
    );
    let mut counts = std::collections::BTreeMap::new();
    for (i, &grey) in robot.cells.iter().enumerate() {
        let (row, col) = (i / robot.width, i % robot.width);
        let cell = proto::grid::Cell::new(col as i32, (height - 1 - row) as i32);
        let want = match grey {
            254 => Occ::Free,
            0 => Occ::Occupied,
            205 => Occ::Unknown,
            other => panic!("grey {other} in a grid"),
        };
        *counts.entry(grey).or_insert(0usize) += 1;
        assert_eq!(truth.get(cell), want, "cell {cell:?}");
    }
    assert!(
        counts.len() == 3,
        "the robot's map holds free, occupied and unknown cells: {counts:?}"
    );
    // The same through our own loader (the YAML's thresholds and origin included).
    let loaded = world_server::map::load_ros_map(&robot_map).expect("the YAML loads");
    assert_eq!((&loaded.grid, loaded.info), (&truth, header.map));

    // Every robot of the new run stood on free cells of the robot's map, from its start on.
    let rows = csv(&second.join("metrics.csv"));
    for robot in 0..2 {
        let mine: Vec<_> = rows
            .iter()
            .filter(|r| r["robot"] == robot.to_string())
            .collect();
        assert!(!mine.is_empty(), "robot {robot} has rows");
        for row in mine {
            let at = Metres::new(num(row, "x"), num(row, "y"));
            assert_eq!(
                truth.get(header.map.cell_of(at)),
                Occ::Free,
                "robot {robot} at {at:?}, step {}",
                row["step"]
            );
        }
    }
}
