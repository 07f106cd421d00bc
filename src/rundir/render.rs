//! PNG pictures of a run: the truth map and each robot's final planning grid with its
//! trajectory. Cells are drawn as `scale × scale` squares, row 0 (the bottom of the world) at the
//! bottom of the picture.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use anyhow::Context;
use proto::geom::{MapInfo, Metres};
use proto::grid::{Grid, Occ};

/// Colours of robots' trajectories, reused cyclically.
/// ColorBrewer's Set1 (with teal for its grey): eight colours told apart on a white map.
const PALETTE: [[u8; 3]; 8] = [
    [228, 26, 28],
    [55, 126, 184],
    [77, 175, 74],
    [152, 78, 163],
    [255, 127, 0],
    [166, 86, 40],
    [247, 129, 191],
    [0, 160, 160],
];

/// Robot `i`'s colour: the one palette of every picture, plot, MCAP file and the viewer's page.
pub fn robot_colour(i: usize) -> [u8; 3] {
    PALETTE[i % PALETTE.len()]
}

/// The palette as CSS colours (`#rrggbb`), robot 0 first: what the viewer's page draws with.
pub fn palette_css() -> Vec<String> {
    PALETTE
        .iter()
        .map(|[r, g, b]| format!("#{r:02x}{g:02x}{b:02x}"))
        .collect()
}

/// An RGB image under construction.
pub struct Picture {
    width: u32,
    height: u32,
    scale: u32,
    rgb: Vec<u8>,
    info: MapInfo,
}

impl Picture {
    /// Draws a grid (free white, occupied black, unknown grey), scaled to about 800 px wide.
    pub fn of_grid(g: &Grid, info: MapInfo) -> Picture {
        let scale = (800 / g.width().max(1)).clamp(1, 8);
        let (width, height) = (g.width() * scale, g.height() * scale);
        let mut p = Picture {
            width,
            height,
            scale,
            rgb: vec![0; (width * height * 3) as usize],
            info,
        };
        for (i, &c) in g.cells().iter().enumerate() {
            let cell = g.cell_of(i);
            let col = match c {
                Occ::Free => [255, 255, 255],
                Occ::Occupied => [0, 0, 0],
                Occ::Unknown => [160, 160, 160],
            };
            p.fill_cell(cell.x, cell.y, col);
        }
        p
    }

    fn fill_cell(&mut self, cx: i32, cy: i32, col: [u8; 3]) {
        let s = self.scale as i32;
        let h = self.height as i32;
        for dy in 0..s {
            for dx in 0..s {
                self.put(cx * s + dx, h - 1 - (cy * s + dy), col);
            }
        }
    }

    fn put(&mut self, x: i32, y: i32, col: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as u32) < self.width && (y as u32) < self.height {
            let i = ((y as u32 * self.width + x as u32) * 3) as usize;
            self.rgb[i..i + 3].copy_from_slice(&col);
        }
    }

    /// Pixel of a metric point.
    fn pixel(&self, p: Metres) -> (f64, f64) {
        let s = f64::from(self.scale);
        let (cx, cy) = self.info.in_cells(p);
        let px = cx * s;
        let py = f64::from(self.height) - cy * s;
        (px, py)
    }

    /// A polyline through metric points.
    pub fn path(&mut self, points: &[Metres], col: [u8; 3]) {
        for w in points.windows(2) {
            let (a, b) = (self.pixel(w[0]), self.pixel(w[1]));
            let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as i32).max(1);
            for k in 0..=n {
                let t = f64::from(k) / f64::from(n);
                self.put(
                    (a.0 + t * (b.0 - a.0)) as i32,
                    (a.1 + t * (b.1 - a.1)) as i32,
                    col,
                );
            }
        }
    }

    /// A filled square marker at a metric point.
    pub fn marker(&mut self, p: Metres, col: [u8; 3]) {
        let (px, py) = self.pixel(p);
        let r = (self.scale as i32).max(2);
        for dy in -r..=r {
            for dx in -r..=r {
                self.put(px as i32 + dx, py as i32 + dy, col);
            }
        }
    }

    /// Colours one grid cell.
    pub fn cell(&mut self, c: proto::grid::Cell, col: [u8; 3]) {
        self.fill_cell(c.x, c.y, col);
    }

    pub fn save(&self, path: &Path) -> anyhow::Result<()> {
        write_png(path, self.width, self.height, &self.rgb)
    }

    /// The picture as PNG bytes.
    pub fn png(&self) -> anyhow::Result<Vec<u8>> {
        let mut out = Vec::new();
        encode_png(&mut out, self.width, self.height, &self.rgb)?;
        Ok(out)
    }
}

/// Writes 8-bit RGB pixels (row 0 at the top) as a PNG file.
pub fn write_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> anyhow::Result<()> {
    let file = File::create(path).with_context(|| format!("creating {}", path.display()))?;
    encode_png(BufWriter::new(file), width, height, rgb)
        .with_context(|| format!("writing {}", path.display()))
}

/// Encodes 8-bit RGB pixels (row 0 at the top) as PNG into `w`.
pub fn encode_png<W: std::io::Write>(
    w: W,
    width: u32,
    height: u32,
    rgb: &[u8],
) -> anyhow::Result<()> {
    let mut enc = png::Encoder::new(w, width, height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header()?;
    w.write_image_data(rgb)?;
    Ok(())
}
