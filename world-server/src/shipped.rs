//! The maps the binary carries: every map of the source tree's `configs/maps/` — its YAML, its
//! image and its row of `configs/maps/SOURCES.md` (where it comes from, under which licence) —
//! compiled in, so that the `swarm` binary alone runs every shipped scenario, wherever it is
//! copied. A map file on disk of the same name still wins ([`crate::scenario::locate_map`]).
//!
//! They are stored as they are in the tree (1.9 MB of PGM and PNG): compressing them would
//! save about a megabyte of a binary of well over a hundred, not worth a decompressor.
//!
//! **Invariant:** every map in `configs/maps/` is carried, loads to the same grid as its file,
//! and has its provenance row (test: `every_map_of_the_tree_is_carried_and_loads_as_its_file`).

use std::path::{Path, PathBuf};

use crate::map::{map_of, parse_map_yaml, MapError, TruthMap};

/// One map the binary carries.
#[derive(Debug, PartialEq)]
pub struct Shipped {
    /// Its name, what `world.map` takes.
    pub name: &'static str,
    yaml: &'static str,
    image: &'static [u8],
}

/// A carried map from `configs/maps/NAME.yaml` and its image `NAME.EXT`.
macro_rules! shipped {
    ($name:literal, $ext:literal) => {
        Shipped {
            name: $name,
            yaml: include_str!(concat!("../../configs/maps/", $name, ".yaml")),
            image: include_bytes!(concat!("../../configs/maps/", $name, ".", $ext)),
        }
    };
}

/// Every map the binary carries, by name.
pub static SHIPPED: [Shipped; 8] = [
    shipped!("acapulco_convention_center", "pgm"),
    shipped!("aces3_austin", "png"),
    shipped!("aws_small_house", "pgm"),
    shipped!("fr079", "pgm"),
    shipped!("fr101", "pgm"),
    shipped!("intel_lab", "pgm"),
    shipped!("mit_killian_court", "png"),
    shipped!("willow_garage", "pgm"),
];

/// Where each map comes from: `configs/maps/SOURCES.md`, whose table has a row per map.
const SOURCES: &str = include_str!("../../configs/maps/SOURCES.md");

/// Where a map comes from, as `configs/maps/SOURCES.md` says.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Provenance {
    /// The repository (and commit) it was taken from.
    pub source: String,
    /// The repository's licence, or what is known of the data's.
    pub licence: String,
    /// What the building is.
    pub description: String,
}

impl Shipped {
    /// The carried map of this name.
    pub fn find(name: &str) -> Option<&'static Shipped> {
        SHIPPED.iter().find(|m| m.name == name)
    }

    /// Every carried map's name, `|`-separated (for messages).
    pub fn names() -> String {
        SHIPPED.iter().map(|m| m.name).collect::<Vec<_>>().join("|")
    }

    /// The map: its YAML read as if it were the file `configs/maps/NAME.yaml`.
    pub fn load(&self) -> Result<TruthMap, MapError> {
        let yaml = parse_map_yaml(self.yaml, &self.pseudo_path())?;
        map_of(&yaml, self.image)
    }

    /// The path its YAML had in the source tree, for messages.
    fn pseudo_path(&self) -> PathBuf {
        Path::new("configs/maps").join(format!("{}.yaml", self.name))
    }

    /// Its row of `SOURCES.md` (empty fields if it has none: the test makes sure it has).
    pub fn provenance(&self) -> Provenance {
        provenance_in(SOURCES, self.name).unwrap_or_default()
    }
}

/// The row of `name` in the table of a `SOURCES.md` text: its columns are name (file), source
/// repository @ commit, path, licence, sizes, resolution, yaml, free, cc, description.
fn provenance_in(text: &str, name: &str) -> Option<Provenance> {
    text.lines().find_map(|line| {
        let cells: Vec<&str> = line
            .trim()
            .strip_prefix('|')?
            .split('|')
            .map(str::trim)
            .collect();
        // `intel_lab (.pgm)`: the name, then the image's kind (the header says `name (file)`).
        let (first, kind) = cells.first()?.split_once(" (")?;
        (first == name && kind.starts_with('.') && cells.len() >= 10).then(|| Provenance {
            source: cells[1].to_string(),
            licence: cells[3].to_string(),
            description: cells[9].to_string(),
        })
    })
}

/// Where a scenario's map comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum MapSource {
    /// A `map_server` YAML on disk (an absolute path).
    File(PathBuf),
    /// A map the binary carries.
    Shipped(&'static Shipped),
}

impl MapSource {
    /// Loads the map.
    pub fn load(&self) -> Result<TruthMap, MapError> {
        match self {
            MapSource::File(path) => crate::map::load_ros_map(path),
            MapSource::Shipped(m) => m.load(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_map_of_the_tree_is_carried_and_loads_as_its_file() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/maps");
        let mut in_tree: Vec<String> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .flatten()
            .filter_map(|e| {
                let n = e.file_name().to_string_lossy().into_owned();
                n.strip_suffix(".yaml").map(String::from)
            })
            .collect();
        in_tree.sort();
        let carried: Vec<&str> = SHIPPED.iter().map(|m| m.name).collect();
        assert_eq!(
            in_tree, carried,
            "configs/maps/ and SHIPPED name the same maps"
        );
        for m in &SHIPPED {
            let file = crate::map::load_ros_map(&dir.join(format!("{}.yaml", m.name)))
                .unwrap_or_else(|e| panic!("{e}"));
            let carried = m.load().unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(carried.info, file.info, "{}", m.name);
            assert!(carried.grid == file.grid, "{}: the same cells", m.name);
            let p = m.provenance();
            assert!(
                !p.source.is_empty() && !p.licence.is_empty() && !p.description.is_empty(),
                "{}: SOURCES.md has its row: {p:?}",
                m.name
            );
        }
    }

    #[test]
    fn a_provenance_row_is_found_by_the_name_before_its_file_kind() {
        let text = "| name (file) | source | path | licence | px | res | yaml | free | cc | about |\n\
                    |---|---|---|---|---|---|---|---|---|---|\n\
                    | fr079 (.pgm) | repo @ abc | p | BSD | 1 → 1 | 0.1 | source | 0.4 | 1.0 | Offices. |\n";
        let p = provenance_in(text, "fr079").unwrap_or_default();
        assert_eq!(
            (
                p.source.as_str(),
                p.licence.as_str(),
                p.description.as_str()
            ),
            ("repo @ abc", "BSD", "Offices.")
        );
        assert_eq!(provenance_in(text, "fr07"), None);
        assert_eq!(provenance_in(text, "name"), None);
    }

    #[test]
    fn a_map_is_found_by_name_only() {
        assert_eq!(
            Shipped::find("intel_lab").map(|m| m.name),
            Some("intel_lab")
        );
        assert!(Shipped::find("intel_lab.yaml").is_none() && Shipped::find("").is_none());
        assert!(Shipped::names().contains("aces3_austin|"));
    }
}
