//! A scenario made ready to run, the one way every entry point does it (`swarm run`, `swarm
//! replay`, `swarm sweep`'s checks, the world-server): a file or the embedded default, with `--set`
//! overrides; a map name found relative to the file's directory and made an absolute path;
//! `radio.range_pct_of_diagonal` turned into `radio.range_m`; a left-out `max_steps` derived from
//! the world's reachable area
//! ([`Scenario::derived_max_steps`](proto::scenario::Scenario::derived_max_steps)).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use proto::grid::Occ;
use proto::scenario::GeneratedWorld;
use proto::scenario::Scenario;

use crate::shipped::{MapSource, Shipped};
use crate::world::World;

/// The embedded default scenario (`configs/default.toml`).
pub const DEFAULT_SCENARIO: &str = include_str!("../../configs/default.toml");

/// A resolved scenario and where its map comes from (`None` for a generated world).
pub struct Resolved {
    /// `world.map` is the map file's absolute path, or the name of a map the binary carries,
    /// unless the world is generated.
    pub scenario: Scenario,
    pub map: Option<MapSource>,
}

impl Resolved {
    /// The world's short name: the map file's stem, or the generated world's kind.
    pub fn name(&self) -> String {
        Path::new(&self.scenario.world.map)
            .file_stem()
            .map_or("run".into(), |n| n.to_string_lossy().into_owned())
    }
}

/// Loads `file` (the embedded default without one), applies `set`, finds the map and computes
/// the radio range a share of the diagonal asks for.
pub fn resolve(file: Option<&Path>, set: &[String]) -> anyhow::Result<Resolved> {
    let (mut s, base) = match file {
        Some(p) => (
            Scenario::load(p, set)?,
            p.parent().unwrap_or(Path::new(".")).to_path_buf(),
        ),
        None => (
            Scenario::from_toml(DEFAULT_SCENARIO, set)?,
            PathBuf::from("."),
        ),
    };
    let map = if s.world_is_generated() {
        None
    } else {
        let map = match locate_map(&s.world.map, &base)? {
            MapSource::File(file) => MapSource::File(
                file.canonicalize()
                    .with_context(|| format!("resolving {}", file.display()))?,
            ),
            shipped => shipped,
        };
        s.world.map = match &map {
            MapSource::File(file) => file.to_string_lossy().into_owned(),
            MapSource::Shipped(m) => m.name.to_string(),
        };
        Some(map)
    };
    if let Some(pct) = s.radio.range_pct_of_diagonal {
        s.radio.range_m = pct / 100.0 * environment_diagonal_m(&s, map.as_ref())?;
    }
    if s.max_steps.is_none() {
        let world = World::build(&s, map.as_ref())?;
        s.max_steps = Some(s.derived_max_steps(world.reachable.count(Occ::Free)));
    }
    Ok(Resolved { scenario: s, map })
}

/// Finds the map of `world.map`: a map YAML's path (relative to `base`); or a map name, looked
/// up as `NAME.yaml` in `base`, `base/maps` and `./configs/maps` — a file on disk wins — and
/// then among the maps the binary carries ([`crate::shipped`]).
pub fn locate_map(name: &str, base: &Path) -> anyhow::Result<MapSource> {
    let direct = base.join(name);
    if direct.is_file() {
        return Ok(MapSource::File(direct));
    }
    let file = format!("{name}.yaml");
    let dirs = [
        base.to_path_buf(),
        base.join("maps"),
        PathBuf::from("configs/maps"),
    ];
    if let Some(found) = dirs.iter().map(|d| d.join(&file)).find(|p| p.is_file()) {
        return Ok(MapSource::File(found));
    }
    if let Some(m) = Shipped::find(name) {
        return Ok(MapSource::Shipped(m));
    }
    // Not found: name what there is, so that a typo is one look away from its fix.
    let mut on_disk: Vec<String> = dirs
        .iter()
        .filter_map(|d| std::fs::read_dir(d).ok())
        .flatten()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            name.strip_suffix(".yaml").map(str::to_string)
        })
        .filter(|n| Shipped::find(n).is_none())
        .collect();
    on_disk.sort();
    on_disk.dedup();
    let on_disk = if on_disk.is_empty() {
        String::new()
    } else {
        format!("; map files here: {}", on_disk.join("|"))
    };
    bail!(
        "world.map = {name:?}: no such map file, no {file} in {}, and no map of that name in \
         this binary; shipped maps: {}{on_disk}; generated worlds: {} (`swarm maps` lists them)",
        dirs.iter()
            .map(|d| d.display().to_string())
            .collect::<Vec<_>>()
            .join(", "),
        Shipped::names(),
        GeneratedWorld::names()
    )
}

/// The diagonal of the environment's rectangle: a generated world's extent, or the bounding box
/// of a map's known (free or occupied) cells at the map's own resolution — the thesis's
/// "maximum communication range".
pub fn environment_diagonal_m(s: &Scenario, map: Option<&MapSource>) -> anyhow::Result<f64> {
    let Some(source) = map else {
        return Ok(s.world.width_m.hypot(s.world.height_m));
    };
    let map = source.load()?;
    let g = &map.grid;
    let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
    for (i, &v) in g.cells().iter().enumerate() {
        if v != Occ::Unknown {
            let c = g.cell_of(i);
            (x0, y0) = (x0.min(c.x.unsigned_abs()), y0.min(c.y.unsigned_abs()));
            (x1, y1) = (x1.max(c.x.unsigned_abs()), y1.max(c.y.unsigned_abs()));
        }
    }
    if x0 > x1 {
        bail!("world.map = {:?}: the map has no known cell", s.world.map);
    }
    let cells = f64::from(x1 - x0 + 1).hypot(f64::from(y1 - y0 + 1));
    Ok(cells * map.info.resolution_m)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mistyped `world.map` once got an error that named no shipped map and no generated world.
    #[test]
    fn a_mistyped_map_name_gets_the_maps_and_worlds_it_could_be() {
        let Err(e) = locate_map("intel_lba", Path::new(".")) else {
            panic!("intel_lba is no map");
        };
        let e = e.to_string();
        assert!(e.contains("intel_lab") && e.contains("aces3_austin"), "{e}");
        assert!(e.contains("two-corridors") && e.contains("library"), "{e}");
    }

    #[test]
    fn the_default_resolves_to_the_carried_map_and_a_range_from_the_diagonal() {
        let r = resolve(None, &["radio.range_pct_of_diagonal=50".into()])
            .unwrap_or_else(|e| panic!("{e:#}"));
        // Run from the crate's directory: no configs/maps here, so the carried map.
        assert_eq!(r.map, Shipped::find("intel_lab").map(MapSource::Shipped));
        assert_eq!(r.scenario.world.map, "intel_lab");
        let d = environment_diagonal_m(&r.scenario, r.map.as_ref()).unwrap_or_default();
        assert!(d > 1.0);
        assert!((r.scenario.radio.range_m - d / 2.0).abs() < 1e-9);
        assert_eq!(r.name(), "intel_lab");
    }

    #[test]
    fn a_left_out_step_limit_is_derived_from_the_reachable_area_and_a_given_one_kept() {
        let steps = |set: &[&str]| {
            let set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
            resolve(None, &set)
                .unwrap_or_else(|e| panic!("{e:#}"))
                .scenario
                .max_steps
        };
        // intel_lab: 9 222 reachable cells of 0.2 m (369 m²): 1 476 steps, below the floor.
        assert_eq!(steps(&[]), Some(3000));
        assert_eq!(steps(&["max_steps=17"]), Some(17));
        // mit_killian_court: 72 542 cells (2 901.7 m²) at 0.5 m a step: 2 × 2 901.7 / 0.5, rounded.
        assert_eq!(steps(&["world.map=mit_killian_court"]), Some(11_607));
        // Half the speed, twice the steps (23 213.4, rounded).
        assert_eq!(
            steps(&["world.map=mit_killian_court", "robots.speed_m_per_s=0.25"]),
            Some(23_213)
        );
    }

    #[test]
    fn a_generated_world_has_no_map_file_and_the_extent_as_diagonal() {
        let set = [
            "world.map=office".into(),
            "world.width_m=30".into(),
            "world.height_m=40".into(),
            "radio.range_pct_of_diagonal=10".into(),
        ];
        let r = resolve(None, &set).unwrap_or_else(|e| panic!("{e:#}"));
        assert!(r.map.is_none());
        assert_eq!(r.name(), "office");
        assert!((r.scenario.radio.range_m - 5.0).abs() < 1e-9);
    }

    #[test]
    fn an_unknown_map_is_named() {
        let err = resolve(None, &["world.map=no_such_map".into()]).err();
        assert!(err.is_some_and(|e| e.to_string().contains("no_such_map")));
    }
}
