//! The run directory's grids (`grids/`) as ROS `map_server` maps: each grid a PGM, and beside it
//! the YAML that `map_server`, nav2's `map_server` and our own `world.map` load it by.
//!
//! The PGM (P5) holds one grey per cell: 254 free, 0 occupied, 205 unknown, the top row first
//! (the largest y; proto's grid row 0 is the bottom). The YAML names the PGM by its file name
//! (relative to the YAML, so the pair can be moved together), the run's map frame (`resolution`,
//! `origin` = the lower-left corner of cell (0, 0), yaw 0) and the thresholds that give the
//! three greys back exactly (see [`OCCUPIED_THRESH`](crate::rundir::grids::OCCUPIED_THRESH)).

use std::path::Path;

use anyhow::{bail, Context};
use proto::geom::MapInfo;
use proto::grid::{Cell, Grid, Occ};

/// The grey of a free cell.
pub const FREE_GREY: u8 = 254;
/// The grey of an occupied cell.
pub const OCCUPIED_GREY: u8 = 0;
/// The grey of an unknown cell.
pub const UNKNOWN_GREY: u8 = 205;

/// `occupied_thresh` of every grid's YAML. `map_server` reads grey v (with `negate: 0`) as the
/// occupancy p = (255 − v) / 255: free 254 → 0.0039, unknown 205 → 0.196, occupied 0 → 1.0; in
/// `trinary` mode a cell is occupied if p > `occupied_thresh`, free if p < `free_thresh`, else
/// unknown. 0.65 and 0.1 lie far from all three values, so the greys come back as they were
/// written whether a reader compares strictly or not (ROS 1's `map_saver` writes `free_thresh:
/// 0.196`, 8e-5 below the unknown grey's p; nav2's default 0.25 would read unknown as free).
pub const OCCUPIED_THRESH: f64 = 0.65;
/// `free_thresh` of every grid's YAML: see [`OCCUPIED_THRESH`].
pub const FREE_THRESH: f64 = 0.1;

/// The grey of a cell in the PGM.
pub fn grey(v: Occ) -> u8 {
    match v {
        Occ::Free => FREE_GREY,
        Occ::Occupied => OCCUPIED_GREY,
        Occ::Unknown => UNKNOWN_GREY,
    }
}

/// Writes `grid`, a grid of the map frame `info`, as the PGM `pgm` and its `map_server` YAML
/// beside it (the same name ending in `.yaml`), so that the grid loads like any other map
/// (`world.map = "…/grids/robot_0_planning.yaml"`).
pub fn write_map(pgm: &Path, grid: &Grid, info: MapInfo) -> anyhow::Result<()> {
    if (grid.width(), grid.height()) != (info.width, info.height) {
        bail!(
            "{}: the grid has {}x{} cells, the map frame {}x{}",
            pgm.display(),
            grid.width(),
            grid.height(),
            info.width,
            info.height
        );
    }
    let Some(image) = pgm.file_name().and_then(|n| n.to_str()) else {
        bail!("{}: not a file name a YAML can give", pgm.display());
    };
    write_pgm(pgm, grid)?;
    let yaml = pgm.with_extension("yaml");
    std::fs::write(&yaml, map_yaml(image, info))
        .with_context(|| format!("writing {}", yaml.display()))
}

/// Writes `grid` as a PGM (P5; free 254, occupied 0, unknown 205; the top row is the largest y).
fn write_pgm(path: &Path, grid: &Grid) -> anyhow::Result<()> {
    let (w, h) = (grid.width(), grid.height());
    let mut out = format!("P5\n{w} {h}\n255\n").into_bytes();
    out.reserve(w as usize * h as usize);
    for y in (0..h as i32).rev() {
        for x in 0..w as i32 {
            out.push(grey(grid.get(Cell::new(x, y))));
        }
    }
    std::fs::write(path, out).with_context(|| format!("writing {}", path.display()))
}

/// The `map_server` YAML of an image named `image` (relative to the YAML) in the frame `info`.
pub fn map_yaml(image: &str, info: MapInfo) -> String {
    format!(
        "image: {image}\n\
         resolution: {}\n\
         origin: [{}, {}, 0.0]\n\
         negate: 0\n\
         occupied_thresh: {}\n\
         free_thresh: {}\n\
         mode: trinary\n",
        number(info.resolution_m),
        number(info.origin_x_m),
        number(info.origin_y_m),
        number(OCCUPIED_THRESH),
        number(FREE_THRESH),
    )
}

/// A YAML float that reads back as the same `f64`: Rust's shortest round-trip digits (never an
/// exponent), with a `.0` on whole numbers so that every YAML reader takes it as a float.
fn number(v: f64) -> String {
    let s = v.to_string();
    if v.is_finite() && !s.contains('.') {
        format!("{s}.0")
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use world_server::map::load_ros_map;

    /// A fresh directory, removed on drop.
    struct Dir(std::path::PathBuf);

    impl Dir {
        fn new() -> Dir {
            use std::sync::atomic::{AtomicU32, Ordering};
            static N: AtomicU32 = AtomicU32::new(0);
            let p = std::env::temp_dir().join(format!(
                "swarm-grids-{}-{}",
                std::process::id(),
                N.fetch_add(1, Ordering::Relaxed)
            ));
            std::fs::create_dir_all(&p).expect("a temp dir");
            Dir(p)
        }
    }

    impl Drop for Dir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    /// map_server's trinary rule, as ROS 1's `map_server` and nav2's `map_io` state it, both
    /// strict and not: every grey we write comes back as what it was written for.
    #[test]
    fn map_server_reads_the_three_greys_back() {
        for v in [Occ::Free, Occ::Occupied, Occ::Unknown] {
            let p = (255.0 - f64::from(grey(v))) / 255.0;
            let strict = if p > OCCUPIED_THRESH {
                Occ::Occupied
            } else if p < FREE_THRESH {
                Occ::Free
            } else {
                Occ::Unknown
            };
            let loose = if p >= OCCUPIED_THRESH {
                Occ::Occupied
            } else if p <= FREE_THRESH {
                Occ::Free
            } else {
                Occ::Unknown
            };
            assert_eq!((strict, loose), (v, v), "grey {} (p = {p})", grey(v));
            // nav2 computes 1 − v/255 instead: the same class.
            let nav2 = 1.0 - f64::from(grey(v)) / 255.0;
            assert!((nav2 - p).abs() < 1e-12);
        }
    }

    #[test]
    fn the_yaml_names_the_image_frame_and_thresholds() {
        let info = MapInfo {
            width: 3,
            height: 2,
            resolution_m: 0.2,
            origin_x_m: -12.5,
            origin_y_m: 3.0,
        };
        assert_eq!(
            map_yaml("robot_0_planning.pgm", info),
            "image: robot_0_planning.pgm\nresolution: 0.2\norigin: [-12.5, 3.0, 0.0]\n\
             negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.1\nmode: trinary\n"
        );
    }

    #[test]
    fn a_grid_that_does_not_fit_its_frame_is_an_error_and_writes_nothing() {
        let dir = Dir::new();
        let pgm = dir.0.join("g.pgm");
        let info = MapInfo::at_origin(3, 3, 0.1);
        let err = write_map(&pgm, &Grid::new(2, 3, Occ::Free), info)
            .err()
            .map(|e| e.to_string());
        assert!(err.is_some_and(|e| e.contains("2x3")));
        assert!(!pgm.exists() && !dir.0.join("g.yaml").exists());
    }

    fn arb_grid() -> impl Strategy<Value = Grid> {
        (1u32..12, 1u32..12).prop_flat_map(|(w, h)| {
            prop::collection::vec(
                prop::sample::select(vec![Occ::Free, Occ::Occupied, Occ::Unknown]),
                (w * h) as usize,
            )
            .prop_map(move |cells| {
                let mut g = Grid::new(w, h, Occ::Unknown);
                g.cells_mut().copy_from_slice(&cells);
                g
            })
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// What a run writes loads back through our own `world.map` loader as the same grid in
        /// the same frame, bit for bit (origin and resolution included).
        #[test]
        fn a_written_grid_loads_back_as_the_same_map(
            grid in arb_grid(),
            resolution_m in 0.01f64..2.0,
            origin_x_m in -1000.0f64..1000.0,
            origin_y_m in -1000.0f64..1000.0,
        ) {
            let dir = Dir::new();
            let info = MapInfo {
                width: grid.width(),
                height: grid.height(),
                resolution_m,
                origin_x_m,
                origin_y_m,
            };
            let pgm = dir.0.join("robot_1_planning.pgm");
            write_map(&pgm, &grid, info).map_err(|e| TestCaseError::fail(e.to_string()))?;
            let map = load_ros_map(&dir.0.join("robot_1_planning.yaml"))
                .map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert_eq!(map.info, info);
            prop_assert_eq!(map.grid, grid);
        }
    }
}
