//! The truth map: loading ROS `map_server` maps and resampling them to the world's resolution.
//!
//! docs/design.md §3: the world-server loads a truth map from a ROS `map_server` YAML plus PGM/PNG
//! image (keys `image`, `resolution`, `origin`, `negate`, `occupied_thresh`, `free_thresh`,
//! optional `mode`), then resamples it to `world.resolution_m` so that speeds and ranges are
//! physical, not per-cell. Resampling is conservative: a coarse cell is occupied if any fine cell
//! in it is, and free only if all of them are free, which also erases the one-pixel free laser
//! streaks that raw SLAM maps carry into the unknown.
//!
//! The YAML reader understands the flat subset `map_server` files use (`key: value` lines,
//! `[a, b, c]` lists, `#` comments, quoted scalars) and is total: anything else is a
//! [`MapError`](crate::map::MapError) naming the file and the line, never a panic.

use std::io::Read;
use std::path::{Path, PathBuf};

use proto::geom::MapInfo;
use proto::grid::{Cell, Grid, Occ, MAX_CELLS};

use crate::image::{ImageError, Mode, Thresholds};

/// A map in the world frame: its frame (size, resolution, origin) and its cells.
#[derive(Clone, Debug, PartialEq)]
pub struct TruthMap {
    pub info: MapInfo,
    pub grid: Grid,
}

/// YAML files larger than this are not map descriptions; refusing them bounds the read.
const MAX_YAML_BYTES: u64 = 1 << 20;

#[derive(Debug, thiserror::Error)]
pub enum MapError {
    #[error("{path}: cannot read: {reason}")]
    Io {
        path: PathBuf,
        reason: std::io::Error,
    },
    #[error("{path}: {bytes} bytes is too large for a map YAML (limit {MAX_YAML_BYTES})")]
    YamlTooLarge { path: PathBuf, bytes: u64 },
    #[error("{path}:{line}: {what}")]
    Syntax {
        path: PathBuf,
        line: usize,
        what: String,
    },
    #[error("{path}:{line}: key `{key}` appears twice")]
    DuplicateKey {
        path: PathBuf,
        line: usize,
        key: String,
    },
    #[error("{path}: missing key `{key}`")]
    MissingKey { path: PathBuf, key: &'static str },
    #[error("{path}: key `{key}`: {text:?} is not a finite number")]
    BadNumber {
        path: PathBuf,
        key: &'static str,
        text: String,
    },
    #[error("{path}: key `{key}`: {text:?} is not {expected}")]
    BadValue {
        path: PathBuf,
        key: &'static str,
        text: String,
        expected: &'static str,
    },
    #[error("{path}: resolution {resolution_m} m must be > 0")]
    BadResolution { path: PathBuf, resolution_m: f64 },
    #[error("{path}: thresholds free {free} / occupied {occupied}: need 0 ≤ free < occupied ≤ 1")]
    BadThresholds {
        path: PathBuf,
        free: f64,
        occupied: f64,
    },
    #[error("{path}: {reason}")]
    Image { path: PathBuf, reason: ImageError },
    #[error("cannot resample to resolution {resolution_m} m: must be a positive finite number")]
    BadTargetResolution { resolution_m: f64 },
    #[error("cannot resample a map whose own resolution is {resolution_m} m")]
    BadSourceResolution { resolution_m: f64 },
    #[error("resampling gives {width}x{height} cells, more than the limit of {MAX_CELLS}")]
    ResampleTooLarge { width: u64, height: u64 },
}

/// The contents of a `map_server` YAML, with `image` resolved against the YAML's directory.
#[derive(Clone, Debug, PartialEq)]
pub struct MapYaml {
    pub image: PathBuf,
    pub resolution_m: f64,
    pub origin_x_m: f64,
    pub origin_y_m: f64,
    /// Read and kept, but the world frame is the image frame: like most of ROS, we ignore yaw.
    pub origin_yaw_rad: f64,
    pub thresholds: Thresholds,
}

/// Loads a ROS `map_server` map: the YAML at `yaml_path` and the image it names.
pub fn load_ros_map(yaml_path: &Path) -> Result<TruthMap, MapError> {
    let io = |reason| MapError::Io {
        path: yaml_path.to_path_buf(),
        reason,
    };
    let mut text = Vec::new();
    std::fs::File::open(yaml_path)
        .and_then(|f| f.take(MAX_YAML_BYTES + 1).read_to_end(&mut text))
        .map_err(io)?;
    if text.len() as u64 > MAX_YAML_BYTES {
        return Err(MapError::YamlTooLarge {
            path: yaml_path.to_path_buf(),
            bytes: text.len() as u64,
        });
    }
    let text = String::from_utf8(text).map_err(|e| MapError::Syntax {
        path: yaml_path.to_path_buf(),
        line: 1 + e.as_bytes()[..e.utf8_error().valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count(),
        what: "not valid UTF-8".into(),
    })?;
    let yaml = parse_map_yaml(&text, yaml_path)?;
    let bytes = std::fs::read(&yaml.image).map_err(|reason| MapError::Io {
        path: yaml.image.clone(),
        reason,
    })?;
    map_of(&yaml, &bytes)
}

/// The map a parsed YAML describes, from its image's bytes.
pub fn map_of(yaml: &MapYaml, image: &[u8]) -> Result<TruthMap, MapError> {
    let grid = crate::image::decode(image, &yaml.thresholds).map_err(|reason| MapError::Image {
        path: yaml.image.clone(),
        reason,
    })?;
    let info = MapInfo {
        width: grid.width(),
        height: grid.height(),
        resolution_m: yaml.resolution_m,
        origin_x_m: yaml.origin_x_m,
        origin_y_m: yaml.origin_y_m,
    };
    Ok(TruthMap { info, grid })
}

/// One value of the flat YAML subset.
#[derive(Debug, PartialEq)]
enum Value<'a> {
    Scalar(&'a str),
    List(Vec<&'a str>),
}

impl std::fmt::Display for Value<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Value::Scalar(s) => f.write_str(s),
            Value::List(items) => write!(f, "[{}]", items.join(", ")),
        }
    }
}

/// Cuts a `#` comment (at the line start or after whitespace, outside quotes) off a line.
fn strip_comment(line: &str) -> &str {
    let mut quote = None;
    let mut prev_blank = true;
    for (i, c) in line.char_indices() {
        match (quote, c) {
            (None, '#') if prev_blank => return &line[..i],
            (None, '"' | '\'') => quote = Some(c),
            (Some(q), _) if c == q => quote = None,
            _ => {}
        }
        prev_blank = c.is_whitespace();
    }
    line
}

/// Removes matching surrounding quotes from a scalar.
fn unquote(s: &str) -> Result<&str, String> {
    match s.chars().next() {
        Some(q @ ('"' | '\'')) => s
            .strip_prefix(q)
            .and_then(|r| r.strip_suffix(q))
            .ok_or_else(|| format!("unterminated quote in {s:?}")),
        _ => Ok(s),
    }
}

fn parse_value(v: &str) -> Result<Value<'_>, String> {
    let Some(inner) = v.strip_prefix('[') else {
        return unquote(v).map(Value::Scalar);
    };
    let inner = inner
        .strip_suffix(']')
        .ok_or_else(|| format!("list {v:?} has no closing `]`"))?;
    if inner.contains(['[', ']']) {
        return Err("nested lists are not supported".into());
    }
    if inner.trim().is_empty() {
        return Ok(Value::List(Vec::new()));
    }
    inner
        .split(',')
        .map(|item| unquote(item.trim()))
        .collect::<Result<_, _>>()
        .map(Value::List)
}

/// Parses the flat `key: value` subset into (line, key, value) triples; keys are unique.
fn parse_flat_yaml<'a>(
    text: &'a str,
    path: &Path,
) -> Result<Vec<(usize, &'a str, Value<'a>)>, MapError> {
    let syntax = |line, what: String| MapError::Syntax {
        path: path.to_path_buf(),
        line,
        what,
    };
    let mut entries: Vec<(usize, &str, Value)> = Vec::new();
    for (n, raw) in text.lines().enumerate() {
        let line_no = n + 1;
        let raw = raw.trim_start_matches('\u{feff}');
        let line = strip_comment(raw).trim_end();
        if line.trim().is_empty() || line == "---" || line == "..." {
            continue;
        }
        if line.starts_with(char::is_whitespace) {
            return Err(syntax(
                line_no,
                "indented (nested) YAML is not supported in map files".into(),
            ));
        }
        let Some((key, value)) = line.split_once(':') else {
            return Err(syntax(
                line_no,
                format!("expected `key: value`, found {line:?}"),
            ));
        };
        if key.is_empty() || key.contains(char::is_whitespace) {
            return Err(syntax(line_no, format!("bad key {key:?}")));
        }
        if entries.iter().any(|(_, k, _)| *k == key) {
            return Err(MapError::DuplicateKey {
                path: path.to_path_buf(),
                line: line_no,
                key: key.into(),
            });
        }
        let value = parse_value(value.trim()).map_err(|what| syntax(line_no, what))?;
        entries.push((line_no, key, value));
    }
    Ok(entries)
}

/// Parses the text of a `map_server` YAML found at `yaml_path` (used for messages and to resolve
/// a relative `image`).
pub fn parse_map_yaml(text: &str, yaml_path: &Path) -> Result<MapYaml, MapError> {
    let path = || yaml_path.to_path_buf();
    let keys = Keys {
        entries: parse_flat_yaml(text, yaml_path)?,
        path: yaml_path,
    };
    let image = keys.scalar("image")?;
    if image.is_empty() {
        return Err(keys.bad("image", String::new(), "a file name"));
    }
    let resolution_m = keys.number("resolution", keys.scalar("resolution")?)?;
    if resolution_m <= 0.0 {
        return Err(MapError::BadResolution {
            path: path(),
            resolution_m,
        });
    }
    let origin = match keys.require("origin")? {
        Value::List(items) if (2..=3).contains(&items.len()) => items
            .iter()
            .map(|s| keys.number("origin", s))
            .collect::<Result<Vec<_>, _>>()?,
        other => return Err(keys.bad("origin", other.to_string(), "a list [x, y, yaw]")),
    };
    let negate = match keys.scalar("negate")? {
        "0" | "false" => false,
        "1" | "true" => true,
        other => return Err(keys.bad("negate", other.into(), "0 or 1")),
    };
    let occupied = keys.number("occupied_thresh", keys.scalar("occupied_thresh")?)?;
    let free = keys.number("free_thresh", keys.scalar("free_thresh")?)?;
    if !(0.0 <= free && free < occupied && occupied <= 1.0) {
        return Err(MapError::BadThresholds {
            path: path(),
            free,
            occupied,
        });
    }
    let mode = match keys.get("mode") {
        None => Mode::Trinary,
        Some(Value::Scalar("trinary")) => Mode::Trinary,
        Some(Value::Scalar("scale")) => Mode::Scale,
        Some(Value::Scalar("raw")) => Mode::Raw,
        Some(other) => return Err(keys.bad("mode", other.to_string(), "trinary, scale or raw")),
    };
    let dir = yaml_path.parent().unwrap_or(Path::new("."));
    Ok(MapYaml {
        image: dir.join(image),
        resolution_m,
        origin_x_m: origin[0],
        origin_y_m: origin[1],
        origin_yaw_rad: origin.get(2).copied().unwrap_or(0.0),
        thresholds: Thresholds {
            negate,
            occupied_thresh: occupied,
            free_thresh: free,
            mode,
        },
    })
}

/// The entries of a map YAML at `path`, read by key with errors that name the file.
struct Keys<'a> {
    entries: Vec<(usize, &'a str, Value<'a>)>,
    path: &'a Path,
}

impl<'a> Keys<'a> {
    /// The value of `key`, if the file gives one.
    fn get(&self, key: &str) -> Option<&Value<'a>> {
        self.entries
            .iter()
            .find(|(_, k, _)| *k == key)
            .map(|(_, _, v)| v)
    }

    /// The value of `key`, which the file must give.
    fn require(&self, key: &'static str) -> Result<&Value<'a>, MapError> {
        self.get(key).ok_or(MapError::MissingKey {
            path: self.path.to_path_buf(),
            key,
        })
    }

    /// The single value (not a list) of `key`, which the file must give.
    fn scalar(&self, key: &'static str) -> Result<&'a str, MapError> {
        match self.require(key)? {
            Value::Scalar(s) => Ok(*s),
            list @ Value::List(_) => Err(self.bad(key, list.to_string(), "a single value")),
        }
    }

    /// `text`, given for `key`, as a finite number.
    fn number(&self, key: &'static str, text: &str) -> Result<f64, MapError> {
        match text.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(MapError::BadNumber {
                path: self.path.to_path_buf(),
                key,
                text: text.into(),
            }),
        }
    }

    /// The error for `text`, given for `key`, not being what was `expected`.
    fn bad(&self, key: &'static str, text: String, expected: &'static str) -> MapError {
        MapError::BadValue {
            path: self.path.to_path_buf(),
            key,
            text,
            expected,
        }
    }
}

/// Relative tolerance for cell boundaries that fall on a fine-cell boundary up to rounding.
const EDGE_EPS: f64 = 1e-9;

/// Resamples `map` to `resolution_m`, keeping the origin and covering at least the same extent.
///
/// Coarser (or equal): a new cell is occupied if any old cell overlapping it is, free if all of
/// them are free (and it lies wholly inside the old map), unknown otherwise. Finer: each new cell
/// takes the old cell under its centre.
pub fn resample(map: &TruthMap, resolution_m: f64) -> Result<TruthMap, MapError> {
    if !(resolution_m.is_finite() && resolution_m > 0.0) {
        return Err(MapError::BadTargetResolution { resolution_m });
    }
    let old_m = map.info.resolution_m;
    if !(old_m.is_finite() && old_m > 0.0) {
        return Err(MapError::BadSourceResolution {
            resolution_m: old_m,
        });
    }
    // The side of a new cell in old cells.
    let k = resolution_m / map.info.resolution_m;
    let size = |old: u32| {
        let cells = f64::from(old) / k;
        (cells - cells * EDGE_EPS).ceil().max(0.0)
    };
    let (w, h) = (size(map.info.width), size(map.info.height));
    // `w * h` is NaN for an infinite side times an empty one; each side is checked as well.
    if (w * h).is_nan() || w * h > MAX_CELLS as f64 || w.max(h) > MAX_CELLS as f64 {
        return Err(MapError::ResampleTooLarge {
            width: w as u64,
            height: h as u64,
        });
    }
    let mut grid = Grid::new(w as u32, h as u32, Occ::Unknown);
    for i in 0..grid.len() {
        let c = grid.cell_of(i);
        let v = if k >= 1.0 {
            coarse_cell(&map.grid, c, k)
        } else {
            fine_cell(&map.grid, c, k)
        };
        grid.cells_mut()[i] = v;
    }
    let info = MapInfo {
        width: grid.width(),
        height: grid.height(),
        resolution_m,
        ..map.info
    };
    Ok(TruthMap { info, grid })
}

/// The old cells `lo..hi` along one axis that new cell `n` overlaps (`k` ≥ 1 old cells per new).
fn span(n: i32, k: f64) -> (i32, i32) {
    let (a, b) = (f64::from(n) * k, f64::from(n + 1) * k);
    let lo = (a + a.abs().max(1.0) * EDGE_EPS).floor() as i32;
    let hi = (b - b.abs().max(1.0) * EDGE_EPS).ceil() as i32;
    (lo, hi.max(lo + 1))
}

fn coarse_cell(old: &Grid, c: Cell, k: f64) -> Occ {
    let ((x0, x1), (y0, y1)) = (span(c.x, k), span(c.y, k));
    let (w, h) = (old.width() as i32, old.height() as i32);
    // A cell reaching beyond the old map is partly unknown; only the inside part is visited.
    let mut all_free = x0 >= 0 && y0 >= 0 && x1 <= w && y1 <= h;
    for y in y0.max(0)..y1.min(h) {
        for x in x0.max(0)..x1.min(w) {
            match old.get(Cell::new(x, y)) {
                Occ::Occupied => return Occ::Occupied,
                Occ::Free => {}
                Occ::Unknown => all_free = false,
            }
        }
    }
    if all_free {
        Occ::Free
    } else {
        Occ::Unknown
    }
}

fn fine_cell(old: &Grid, c: Cell, k: f64) -> Occ {
    let x = ((f64::from(c.x) + 0.5) * k).floor() as i32;
    let y = ((f64::from(c.y) + 0.5) * k).floor() as i32;
    old.get(Cell::new(x, y))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A fresh directory under the system temp dir, removed again when dropped.
    struct TempDir(PathBuf);

    impl TempDir {
        fn new() -> TempDir {
            static NEXT: AtomicUsize = AtomicUsize::new(0);
            let n = NEXT.fetch_add(1, Ordering::Relaxed);
            let dir =
                std::env::temp_dir().join(format!("world-core-map-{}-{n}", std::process::id()));
            assert!(std::fs::create_dir_all(&dir).is_ok(), "temp dir {dir:?}");
            TempDir(dir)
        }

        fn write(&self, name: &str, bytes: &[u8]) -> PathBuf {
            let path = self.0.join(name);
            assert!(std::fs::write(&path, bytes).is_ok(), "write {path:?}");
            path
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    const YAML: &str = "image: m.pgm\nresolution: 0.1\norigin: [-1.0, 2.5, 0.0]\nnegate: 0\n\
                        occupied_thresh: 0.65\nfree_thresh: 0.196\n";
    /// 3x2 pixels: top row occupied/free/unknown, bottom row free/free/occupied.
    const PGM: &[u8] = b"P5\n3 2\n255\n\x00\xfe\xcd\xfe\xfe\x00";

    /// Writes a YAML (with `yaml` as its text) and `PGM` as `m.pgm`, then loads the map.
    fn load_with(yaml: &str) -> Result<TruthMap, MapError> {
        let dir = TempDir::new();
        dir.write("m.pgm", PGM);
        load_ros_map(&dir.write("m.yaml", yaml.as_bytes()))
    }

    fn yaml_without(key: &str) -> String {
        YAML.lines()
            .filter(|l| !l.starts_with(key))
            .map(|l| format!("{l}\n"))
            .collect()
    }

    fn yaml_with(key: &str, value: &str) -> String {
        format!("{}{key}: {value}\n", yaml_without(key))
    }

    #[test]
    fn loads_a_pgm_map_with_its_frame() {
        let map = load_with(YAML).expect("valid map loads");
        assert_eq!(map.grid, Grid::from_ascii("#.?\n..#\n"));
        let want = MapInfo {
            width: 3,
            height: 2,
            resolution_m: 0.1,
            origin_x_m: -1.0,
            origin_y_m: 2.5,
        };
        assert_eq!(map.info, want);
    }

    #[test]
    fn loads_png_negated_quoted_and_commented_yaml() {
        let dir = TempDir::new();
        let mut png = Vec::new();
        let mut enc = png::Encoder::new(&mut png, 2, 1);
        enc.set_color(png::ColorType::Grayscale);
        assert!(enc
            .write_header()
            .and_then(|mut w| w.write_image_data(&[255, 0]))
            .is_ok());
        dir.write("map #1.png", &png);
        let yaml = "# A map.\r\n---\nimage: \"map #1.png\"   # quoted, with a hash\nresolution: 0.05\n\
                    origin: [0, 0]\nnegate: true\noccupied_thresh: 0.65\nfree_thresh: 0.196\nmode: scale\n";
        let map = load_ros_map(&dir.write("m.yaml", yaml.as_bytes())).expect("valid map loads");
        assert_eq!(
            map.grid,
            Grid::from_ascii("#.\n"),
            "negate swaps black and white"
        );
        assert_eq!(map.info.resolution_m, 0.05);
    }

    #[test]
    fn image_path_may_be_absolute() {
        let dir = TempDir::new();
        let image = dir.write("abs.pgm", PGM);
        let other = TempDir::new();
        let yaml = yaml_with("image", &image.display().to_string());
        assert!(load_ros_map(&other.write("m.yaml", yaml.as_bytes())).is_ok());
    }

    #[test]
    fn file_errors_name_the_file() {
        let dir = TempDir::new();
        let missing = dir.0.join("nope.yaml");
        assert!(
            matches!(load_ros_map(&missing), Err(MapError::Io { path, .. }) if path == missing)
        );
        let big = dir.write("big.yaml", &vec![b'#'; MAX_YAML_BYTES as usize + 1]);
        assert!(matches!(
            load_ros_map(&big),
            Err(MapError::YamlTooLarge { .. })
        ));
        let binary = dir.write("bin.yaml", b"image: m.pgm\n\xff\xfe\n");
        assert!(matches!(
            load_ros_map(&binary),
            Err(MapError::Syntax { line: 2, .. })
        ));
        let no_image = dir.write("noimg.yaml", yaml_with("image", "absent.pgm").as_bytes());
        let err = load_ros_map(&no_image)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(err.contains("absent.pgm"), "{err}");
    }

    #[test]
    fn image_errors_name_the_image() {
        let dir = TempDir::new();
        let yaml = dir.write("m.yaml", YAML.as_bytes());
        for (bytes, want) in [
            (
                &b"P6 1 1 255\n\0\0\0"[..],
                ImageError::UnsupportedMagic("P6".into()),
            ),
            (b"P5 2 2 255\n\0", ImageError::Truncated { got: 1, want: 4 }),
            (
                b"P5 10000 8000 255\n",
                ImageError::TooLarge {
                    width: 10000,
                    height: 8000,
                },
            ),
        ] {
            let image = dir.write("m.pgm", bytes);
            match load_ros_map(&yaml) {
                Err(MapError::Image { path, reason }) => assert_eq!((path, reason), (image, want)),
                other => panic!("expected an image error, got {other:?}"),
            }
        }
    }

    #[test]
    fn yaml_syntax_errors_give_the_line() {
        for (text, line) in [
            ("image: m.pgm\njust words\n", 2),
            ("image: m.pgm\n  nested: 1\n", 2),
            ("image: \"m.pgm\n", 1),
            ("origin: [1, 2\n", 1),
            ("origin: [[1], 2]\n", 1),
            ("bad key: 1\n", 1),
            (": 1\n", 1),
        ] {
            match load_with(text) {
                Err(MapError::Syntax { line: got, .. }) => assert_eq!(got, line, "{text:?}"),
                other => panic!("{text:?}: expected a syntax error, got {other:?}"),
            }
        }
        let dup = format!("{YAML}resolution: 0.2\n");
        assert!(
            matches!(load_with(&dup), Err(MapError::DuplicateKey { line: 7, key, .. }) if key == "resolution")
        );
    }

    #[test]
    fn yaml_value_errors_name_the_key() {
        for key in [
            "image",
            "resolution",
            "origin",
            "negate",
            "occupied_thresh",
            "free_thresh",
        ] {
            let got = load_with(&yaml_without(key));
            assert!(
                matches!(got, Err(MapError::MissingKey { key: k, .. }) if k == key),
                "{key}: {got:?}"
            );
        }
        for (key, value) in [
            ("resolution", "fast"),
            ("resolution", "nan"),
            ("free_thresh", "inf"),
            ("origin", "[0, x, 0]"),
        ] {
            let got = load_with(&yaml_with(key, value));
            assert!(
                matches!(got, Err(MapError::BadNumber { key: k, .. }) if k == key),
                "{key}: {got:?}"
            );
        }
        for (key, value) in [
            ("image", "\"\""),
            ("image", "[a, b]"),
            ("origin", "3"),
            ("origin", "[1, 2, 3, 4]"),
            ("negate", "2"),
            ("mode", "fancy"),
            ("mode", "[raw]"),
        ] {
            let got = load_with(&yaml_with(key, value));
            assert!(
                matches!(got, Err(MapError::BadValue { key: k, .. }) if k == key),
                "{key}: {got:?}"
            );
        }
        for value in ["0", "-0.1"] {
            assert!(matches!(
                load_with(&yaml_with("resolution", value)),
                Err(MapError::BadResolution { .. })
            ));
        }
        for (free, occ) in [
            ("0.7", "0.65"),
            ("0.65", "0.65"),
            ("-0.1", "0.65"),
            ("0.1", "1.5"),
        ] {
            let yaml = yaml_with("occupied_thresh", occ);
            let yaml = format!(
                "{}free_thresh: {free}\n",
                yaml.lines()
                    .filter(|l| !l.starts_with("free_thresh"))
                    .map(|l| format!("{l}\n"))
                    .collect::<String>()
            );
            assert!(
                matches!(load_with(&yaml), Err(MapError::BadThresholds { .. })),
                "{free} {occ}"
            );
        }
    }

    #[test]
    fn raw_mode_reads_percentages() {
        let dir = TempDir::new();
        dir.write("m.pgm", b"P2 3 1 255\n0 100 255\n");
        let map = load_ros_map(&dir.write("m.yaml", yaml_with("mode", "raw").as_bytes()));
        assert_eq!(map.map(|m| m.grid).ok(), Some(Grid::from_ascii(".#?\n")));
    }

    fn truth(pic: &str, resolution_m: f64) -> TruthMap {
        let grid = Grid::from_ascii(pic);
        let info = MapInfo {
            width: grid.width(),
            height: grid.height(),
            resolution_m,
            origin_x_m: 1.0,
            origin_y_m: -2.0,
        };
        TruthMap { info, grid }
    }

    fn check_resample(pic: &str, from_m: f64, to_m: f64, want: &str) {
        let got = resample(&truth(pic, from_m), to_m).expect("valid resolution");
        assert_eq!(got.grid.to_ascii(), Grid::from_ascii(want).to_ascii());
        assert_eq!(
            (
                got.info.resolution_m,
                got.info.origin_x_m,
                got.info.origin_y_m
            ),
            (to_m, 1.0, -2.0)
        );
        assert_eq!(
            (got.info.width, got.info.height),
            (got.grid.width(), got.grid.height())
        );
    }

    #[test]
    fn coarse_cells_are_conservative() {
        check_resample(
            "....??..\n\
             ......#.\n\
             .?......\n\
             ........\n",
            0.05,
            0.1,
            "..?#\n\
             ?...\n",
        );
    }

    #[test]
    fn one_pixel_free_streaks_are_erased() {
        check_resample(
            "??.???\n\
             ??.???\n\
             ?.????\n",
            0.1,
            0.3,
            "??\n",
        );
    }

    #[test]
    fn partial_coarse_cells_at_the_edge_are_unknown_unless_occupied() {
        // 3 cells of 1 m at 2 m: the last coarse column is half outside the old map.
        check_resample("...\n..#\n", 1.0, 2.0, ".#\n");
        check_resample("...\n...\n...\n", 1.0, 2.0, "??\n.?\n");
        // A non-integer ratio (0.048 → 0.1): fine column 4 spans 0.192–0.240 m and so overlaps
        // both coarse columns 1 and 2, and both become occupied.
        let fine = truth("..........\n....#.....\n..........\n", 0.048);
        let coarse = resample(&fine, 0.1).expect("valid resolution");
        assert_eq!(coarse.grid.to_ascii(), "?????\n.##.?\n");
        assert_eq!((coarse.info.width, coarse.info.height), (5, 2));
    }

    #[test]
    fn finer_cells_take_the_nearest_old_cell_and_equal_is_identity() {
        check_resample("#.\n?.\n", 0.2, 0.1, "##..\n##..\n??..\n??..\n");
        check_resample("#.?\n.#.\n", 0.1, 0.1, "#.?\n.#.\n");
    }

    #[test]
    fn resample_rejects_bad_resolutions() {
        let map = truth("..\n", 0.1);
        for r in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(
                matches!(resample(&map, r), Err(MapError::BadTargetResolution { .. })),
                "{r}"
            );
        }
        assert!(matches!(
            resample(&map, 1e-9),
            Err(MapError::ResampleTooLarge { .. })
        ));
        let broken = TruthMap {
            info: MapInfo {
                resolution_m: 0.0,
                ..map.info
            },
            ..map.clone()
        };
        assert!(matches!(
            resample(&broken, 0.1),
            Err(MapError::BadSourceResolution { .. })
        ));
        // A single huge coarse cell visits only the old map, once.
        assert_eq!(
            resample(&map, 1e9).map(|m| m.grid.to_ascii()).ok(),
            Some("?\n".into())
        );
    }

    /// Where the real maps live; `SWARM_MAPS_DIR` overrides it.
    const MAPS_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/maps");

    /// Size and free fraction of each shipped map, from the maps' SOURCES.md.
    const KNOWN_MAPS: &[(&str, u32, u32, f64)] = &[
        ("intel_lab", 579, 581, 0.595),
        ("fr079", 898, 350, 0.479),
        ("aces3_austin", 1129, 1134, 0.255),
        ("mit_killian_court", 1246, 995, 0.078),
        ("acapulco_convention_center", 1016, 539, 0.744),
        ("willow_garage", 540, 587, 0.442),
        ("fr101", 281, 542, 0.413),
        ("aws_small_house", 397, 246, 0.645),
    ];

    /// The pixel size of an image read from its header alone, independently of the decoder.
    fn header_size(path: &Path) -> Option<(u32, u32)> {
        let bytes = std::fs::read(path).ok()?;
        if bytes.starts_with(b"P5") {
            let head = String::from_utf8_lossy(&bytes[..bytes.len().min(200)]).into_owned();
            let mut it = head
                .split_whitespace()
                .filter(|t| !t.starts_with('#'))
                .skip(1);
            Some((it.next()?.parse().ok()?, it.next()?.parse().ok()?))
        } else {
            let info = png::Decoder::new(std::io::Cursor::new(bytes))
                .read_info()
                .ok()?
                .info()
                .size();
            Some(info)
        }
    }

    #[test]
    fn every_real_map_loads_with_its_image_size() {
        let dir = std::env::var_os("SWARM_MAPS_DIR")
            .map_or_else(|| PathBuf::from(MAPS_DIR), PathBuf::from);
        let mut yamls: Vec<PathBuf> = std::fs::read_dir(&dir)
            .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
            .unwrap_or_default();
        yamls.retain(|p| p.extension().is_some_and(|e| e == "yaml"));
        assert!(!yamls.is_empty(), "no map YAMLs in {dir:?}");
        for yaml in yamls {
            let map = load_ros_map(&yaml).unwrap_or_else(|e| panic!("{e}"));
            let image = parse_map_yaml(&std::fs::read_to_string(&yaml).unwrap_or_default(), &yaml)
                .map(|y| y.image)
                .unwrap_or_default();
            let size = (map.grid.width(), map.grid.height());
            assert_eq!(Some(size), header_size(&image), "{yaml:?}");
            assert_eq!(size, (map.info.width, map.info.height));
            let name = yaml
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or_default();
            if let Some(&(_, w, h, free)) = KNOWN_MAPS.iter().find(|m| m.0 == name) {
                assert_eq!(size, (w, h), "{name}");
                let got = map.grid.count(Occ::Free) as f64 / map.grid.len() as f64;
                assert!(
                    (got - free).abs() < 0.0006,
                    "{name}: free fraction {got}, SOURCES.md says {free}"
                );
            }
            let coarse = resample(&map, 0.2).unwrap_or_else(|e| panic!("{e}"));
            assert!(
                coarse.grid.count(Occ::Free) > 0,
                "{name} keeps free space at 0.2 m"
            );
            let spawn = crate::reachable::spawn_cluster(&coarse.grid, &coarse.info, 4, 1.0, 0.5, 1);
            assert!(spawn.is_ok(), "{name}: {spawn:?}");
        }
    }

    fn arb_yaml_line() -> impl Strategy<Value = String> {
        let key = prop::sample::select(vec![
            "image",
            "resolution",
            "origin",
            "negate",
            "occupied_thresh",
            "free_thresh",
            "mode",
            "x",
        ]);
        (key, "[ -~]{0,12}", prop::bool::ANY).prop_map(|(k, v, list)| {
            if list {
                format!("{k}: [{v}]")
            } else {
                format!("{k}: {v}")
            }
        })
    }

    proptest! {
        #[test]
        fn yaml_parsing_is_total(text in "\\PC{0,80}", lines in prop::collection::vec(arb_yaml_line(), 0..10)) {
            let _ = parse_map_yaml(&text, Path::new("x.yaml"));
            let _ = parse_map_yaml(&lines.join("\n"), Path::new("x.yaml"));
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        #[test]
        fn loading_random_files_is_total(
            yaml in prop::collection::vec(any::<u8>(), 0..100),
            image in prop::collection::vec(any::<u8>(), 0..100),
            p5 in prop::bool::ANY,
        ) {
            let dir = TempDir::new();
            let image = if p5 { [&b"P5 4 4 255\n"[..], &image].concat() } else { image };
            dir.write("m.pgm", &image);
            let _ = load_ros_map(&dir.write("random.yaml", &yaml));
            let _ = load_ros_map(&dir.write("m.yaml", YAML.as_bytes()));
        }
    }
}
