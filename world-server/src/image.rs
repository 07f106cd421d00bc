//! Decoding map images (PGM P2/P5 and PNG) into a ternary [`Grid`](proto::grid::Grid), pixel by
//! pixel as ROS `map_server` classifies them.
//!
//! docs/design.md §3 has the world-server load "the format robotics users already have": a
//! `map_server` YAML beside a PGM or PNG image. This module is the image half (the YAML half and
//! the frame live in [`crate::map`]). Every colour pixel becomes one grey value in `0..=255`
//! units by averaging its colour channels (alpha is not a colour), exactly like `map_server`'s
//! `color_avg`; 16-bit and `maxval ≠ 255` samples are scaled into the same units first, so the
//! thresholds of the YAML mean the same thing for every encoding. Image row 0 is the top of the
//! picture, while grid row 0 is the bottom (proto's convention), so rows are flipped here.
//!
//! Decoding is total: the bytes come from a file, so any input either decodes or gives an
//! [`ImageError`](crate::image::ImageError); sizes are checked against
//! [`MAX_CELLS`](proto::grid::MAX_CELLS) before anything is allocated.

use proto::grid::{Grid, Occ, MAX_CELLS};

/// How pixel values map to occupancy: the `map_server` YAML keys `negate`, `occupied_thresh`,
/// `free_thresh` and `mode`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Thresholds {
    pub negate: bool,
    pub occupied_thresh: f64,
    pub free_thresh: f64,
    pub mode: Mode,
}

/// The `map_server` interpretation mode. `Trinary` and `Scale` differ only for values between the
/// thresholds (unknown vs. a probability); a ternary grid has no probabilities, so both give
/// [`Occ::Unknown`] there.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Mode {
    #[default]
    Trinary,
    Scale,
    /// The grey value *is* the occupancy in percent (0 free … 100 occupied); values above 100
    /// mean unknown.
    Raw,
}

impl Thresholds {
    /// Classifies one grey value in `0.0..=255.0` units (after channel averaging).
    pub fn classify(&self, grey: f64) -> Occ {
        let v = if self.negate { 255.0 - grey } else { grey };
        let p = match self.mode {
            Mode::Raw if v > 100.0 => return Occ::Unknown,
            Mode::Raw => v / 100.0,
            Mode::Trinary | Mode::Scale => (255.0 - v) / 255.0,
        };
        if p > self.occupied_thresh {
            Occ::Occupied
        } else if p < self.free_thresh {
            Occ::Free
        } else {
            Occ::Unknown
        }
    }
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ImageError {
    #[error("not a PGM or PNG image (starts with bytes {0:02x?})")]
    UnknownFormat(Vec<u8>),
    #[error("unsupported netpbm magic {0:?}: only P2 (ASCII) and P5 (binary) greymaps are read")]
    UnsupportedMagic(String),
    #[error("PGM header ends before its {field}")]
    MissingHeaderField { field: &'static str },
    #[error("PGM header field {field} is not a valid number: {text:?}")]
    BadHeaderNumber { field: &'static str, text: String },
    #[error("PGM maxval {0} is outside 1..=65535")]
    BadMaxval(u64),
    #[error("PGM header is not followed by a single whitespace byte before the pixels")]
    NoRasterSeparator,
    #[error("image has no pixels ({width}x{height})")]
    Empty { width: u64, height: u64 },
    #[error("image of {width}x{height} pixels exceeds the limit of {MAX_CELLS} cells")]
    TooLarge { width: u64, height: u64 },
    #[error("pixel data truncated: {got} of {want} samples present")]
    Truncated { got: u64, want: u64 },
    #[error("sample {index} has value {value}, above the PGM maxval {maxval}")]
    SampleAboveMax { index: u64, value: u64, maxval: u64 },
    #[error("sample {index} of the ASCII PGM is not a number: {text:?}")]
    BadSample { index: u64, text: String },
    #[error("PNG: {0}")]
    Png(String),
    #[error("PNG colour type {0} is not supported")]
    PngColour(String),
}

/// Decodes a PGM or PNG image (recognised by its first bytes, not its file name).
pub fn decode(bytes: &[u8], t: &Thresholds) -> Result<Grid, ImageError> {
    match bytes {
        [0x89, b'P', b'N', b'G', ..] => decode_png(bytes, t),
        [b'P', b'5', ..] => decode_pgm(bytes, true, t),
        [b'P', b'2', ..] => decode_pgm(bytes, false, t),
        [b'P', m, ..] => Err(ImageError::UnsupportedMagic(format!("P{}", char::from(*m)))),
        _ => Err(ImageError::UnknownFormat(
            bytes.iter().take(8).copied().collect(),
        )),
    }
}

/// Checks the image size and gives a grid to fill (all unknown).
fn checked_grid(width: u64, height: u64) -> Result<Grid, ImageError> {
    if width == 0 || height == 0 {
        return Err(ImageError::Empty { width, height });
    }
    match (u32::try_from(width), u32::try_from(height)) {
        (Ok(w), Ok(h)) if width * height <= MAX_CELLS => Ok(Grid::new(w, h, Occ::Unknown)),
        _ => Err(ImageError::TooLarge { width, height }),
    }
}

/// Stores pixel `i` (row-major from the image's top row) at its flipped grid position.
fn put(grid: &mut Grid, i: usize, v: Occ) {
    let w = grid.width() as usize;
    let (row, col) = (i / w, i % w);
    let y = grid.height() as usize - 1 - row;
    grid.cells_mut()[y * w + col] = v;
}

/// A read position in a netpbm header or ASCII body.
struct Tokens<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Tokens<'a> {
    /// Skips whitespace and `#` comments (which run to the end of the line).
    fn skip_blank(&mut self) {
        while let Some(&b) = self.bytes.get(self.pos) {
            if b == b'#' {
                while self
                    .bytes
                    .get(self.pos)
                    .is_some_and(|&c| c != b'\n' && c != b'\r')
                {
                    self.pos += 1;
                }
            } else if b.is_ascii_whitespace() || b == 0x0b {
                self.pos += 1;
            } else {
                break;
            }
        }
    }

    /// The next whitespace-delimited token, if any.
    fn next(&mut self) -> Option<&'a [u8]> {
        self.skip_blank();
        let start = self.pos;
        while self
            .bytes
            .get(self.pos)
            .is_some_and(|b| !b.is_ascii_whitespace() && *b != b'#')
        {
            self.pos += 1;
        }
        (self.pos > start).then(|| &self.bytes[start..self.pos])
    }
}

/// Parses a decimal number of at most 18 digits (so it cannot overflow a `u64`).
fn parse_u64(tok: &[u8]) -> Option<u64> {
    if tok.is_empty() || tok.len() > 18 || !tok.iter().all(u8::is_ascii_digit) {
        return None;
    }
    Some(tok.iter().fold(0, |acc, d| acc * 10 + u64::from(d - b'0')))
}

fn header_field(tokens: &mut Tokens<'_>, field: &'static str) -> Result<u64, ImageError> {
    let tok = tokens
        .next()
        .ok_or(ImageError::MissingHeaderField { field })?;
    parse_u64(tok).ok_or_else(|| ImageError::BadHeaderNumber {
        field,
        text: String::from_utf8_lossy(tok).into_owned(),
    })
}

fn decode_pgm(bytes: &[u8], binary: bool, t: &Thresholds) -> Result<Grid, ImageError> {
    let mut tokens = Tokens { bytes, pos: 2 };
    let width = header_field(&mut tokens, "width")?;
    let height = header_field(&mut tokens, "height")?;
    let maxval = header_field(&mut tokens, "maxval")?;
    if !(1..=65535).contains(&maxval) {
        return Err(ImageError::BadMaxval(maxval));
    }
    let mut grid = checked_grid(width, height)?;
    let want = width * height;
    let scale = 255.0 / maxval as f64;
    if binary {
        // Exactly one whitespace byte separates the header from the raster.
        if !bytes.get(tokens.pos).is_some_and(u8::is_ascii_whitespace) {
            return Err(ImageError::NoRasterSeparator);
        }
        let raster = &bytes[tokens.pos + 1..];
        let size = if maxval > 255 { 2 } else { 1 };
        let got = (raster.len() / size) as u64;
        if got < want {
            return Err(ImageError::Truncated { got, want });
        }
        for (i, s) in raster.chunks_exact(size).take(want as usize).enumerate() {
            let value = s.iter().fold(0u64, |acc, &b| acc << 8 | u64::from(b));
            if value > maxval {
                return Err(ImageError::SampleAboveMax {
                    index: i as u64,
                    value,
                    maxval,
                });
            }
            put(&mut grid, i, t.classify(value as f64 * scale));
        }
    } else {
        for i in 0..want {
            let tok = tokens
                .next()
                .ok_or(ImageError::Truncated { got: i, want })?;
            let value = parse_u64(tok).ok_or_else(|| ImageError::BadSample {
                index: i,
                text: String::from_utf8_lossy(tok).into_owned(),
            })?;
            if value > maxval {
                return Err(ImageError::SampleAboveMax {
                    index: i,
                    value,
                    maxval,
                });
            }
            put(&mut grid, i as usize, t.classify(value as f64 * scale));
        }
    }
    Ok(grid)
}

fn png_error(e: png::DecodingError) -> ImageError {
    ImageError::Png(e.to_string())
}

fn decode_png(bytes: &[u8], t: &Thresholds) -> Result<Grid, ImageError> {
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    // EXPAND turns palettes into RGB, sub-byte greys into 8-bit and tRNS into alpha, so only
    // 8/16-bit grey, grey+alpha, RGB and RGBA remain below.
    decoder.set_transformations(png::Transformations::EXPAND);
    decoder.set_ignore_text_chunk(true);
    let header = decoder.read_header_info().map_err(png_error)?;
    let (width, height) = (u64::from(header.width), u64::from(header.height));
    let mut grid = checked_grid(width, height)?;
    let mut reader = decoder.read_info().map_err(png_error)?;
    let mut buf = vec![0; reader.output_buffer_size()];
    let out = reader.next_frame(&mut buf).map_err(png_error)?;
    let (channels, colours) = match out.color_type {
        png::ColorType::Grayscale => (1, 1),
        png::ColorType::GrayscaleAlpha => (2, 1),
        png::ColorType::Rgb => (3, 3),
        png::ColorType::Rgba => (4, 3),
        other => return Err(ImageError::PngColour(format!("{other:?}"))),
    };
    let (sample_bytes, scale) = match out.bit_depth {
        png::BitDepth::Eight => (1, 1.0),
        png::BitDepth::Sixteen => (2, 255.0 / 65535.0),
        other => {
            return Err(ImageError::PngColour(format!(
                "{other:?}-bit after expansion"
            )))
        }
    };
    let pixel_bytes = channels * sample_bytes;
    let row_bytes = width as usize * pixel_bytes;
    for row in 0..height as usize {
        let start = row * out.line_size;
        let line = buf
            .get(start..start + row_bytes)
            .ok_or(ImageError::Truncated {
                got: row as u64 * width,
                want: width * height,
            })?;
        for (col, px) in line.chunks_exact(pixel_bytes).enumerate() {
            let sum: u64 = px
                .chunks_exact(sample_bytes)
                .take(colours)
                .map(|s| s.iter().fold(0u64, |acc, &b| acc << 8 | u64::from(b)))
                .sum();
            let grey = sum as f64 * scale / colours as f64;
            put(&mut grid, row * width as usize + col, t.classify(grey));
        }
    }
    Ok(grid)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    pub(crate) const ROS: Thresholds = Thresholds {
        negate: false,
        occupied_thresh: 0.65,
        free_thresh: 0.196,
        mode: Mode::Trinary,
    };

    fn png_bytes(
        w: u32,
        h: u32,
        colour: png::ColorType,
        depth: png::BitDepth,
        data: &[u8],
    ) -> Vec<u8> {
        let mut out = Vec::new();
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(colour);
        enc.set_depth(depth);
        let written = enc
            .write_header()
            .and_then(|mut wr| wr.write_image_data(data));
        assert!(written.is_ok(), "test PNG encodes");
        out
    }

    #[test]
    fn classify_matches_map_server_on_the_trinary_values() {
        assert_eq!(ROS.classify(254.0), Occ::Free);
        assert_eq!(
            ROS.classify(205.0),
            Occ::Unknown,
            "p = 0.19608 is just above free_thresh"
        );
        assert_eq!(ROS.classify(206.0), Occ::Free);
        assert_eq!(ROS.classify(89.0), Occ::Occupied);
        assert_eq!(ROS.classify(90.0), Occ::Unknown);
        let neg = Thresholds {
            negate: true,
            ..ROS
        };
        assert_eq!(neg.classify(0.0), Occ::Free);
        let raw = Thresholds {
            mode: Mode::Raw,
            ..ROS
        };
        assert_eq!(raw.classify(0.0), Occ::Free);
        assert_eq!(raw.classify(100.0), Occ::Occupied);
        assert_eq!(raw.classify(50.0), Occ::Unknown);
        assert_eq!(raw.classify(255.0), Occ::Unknown);
    }

    #[test]
    fn binary_and_ascii_pgm_flip_rows() {
        let mut p5 = b"P5\n# comment\n3 2\n255\n".to_vec();
        p5.extend_from_slice(&[0, 254, 205, 254, 254, 0]);
        let want = Grid::from_ascii("#.?\n..#\n");
        assert_eq!(decode(&p5, &ROS), Ok(want.clone()));
        let p2 = b"P2 3 2 255\n0 254 205\n254 254 0\n";
        assert_eq!(decode(p2, &ROS), Ok(want.clone()));
        let p5_16 = [
            &b"P5 3 2 65535\n"[..],
            &[0, 0, 0xff, 0xfe, 0xcd, 0xcd, 0xff, 0xfe, 0xff, 0xfe, 0, 0],
        ]
        .concat();
        assert_eq!(decode(&p5_16, &ROS), Ok(want.clone()));
        assert_eq!(
            decode(b"P2 3 2 1\n0 1 0\n1 1 0\n", &ROS),
            Ok(Grid::from_ascii("#.#\n..#\n"))
        );
    }

    #[test]
    fn png_colour_types_average_like_map_server() {
        let want = Grid::from_ascii("#.\n?.\n");
        let grey = png_bytes(
            2,
            2,
            png::ColorType::Grayscale,
            png::BitDepth::Eight,
            &[0, 254, 205, 255],
        );
        assert_eq!(decode(&grey, &ROS), Ok(want.clone()));
        let ga = png_bytes(
            2,
            2,
            png::ColorType::GrayscaleAlpha,
            png::BitDepth::Eight,
            &[0, 9, 254, 0, 205, 255, 255, 1],
        );
        assert_eq!(decode(&ga, &ROS), Ok(want.clone()));
        // (0,0,30) averages to 10, (255,255,252) to 254, (205,200,210) to 205.
        let rgb = [0, 0, 30, 255, 255, 252, 205, 200, 210, 255, 255, 255];
        let rgb = png_bytes(2, 2, png::ColorType::Rgb, png::BitDepth::Eight, &rgb);
        assert_eq!(decode(&rgb, &ROS), Ok(want.clone()));
        let rgba = [
            0, 0, 0, 255, 254, 254, 254, 0, 205, 205, 205, 7, 255, 255, 255, 255,
        ];
        let rgba = png_bytes(2, 2, png::ColorType::Rgba, png::BitDepth::Eight, &rgba);
        assert_eq!(decode(&rgba, &ROS), Ok(want.clone()));
        let g16 = png_bytes(
            2,
            2,
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            &[0, 0, 0xff, 0xfe, 0xcd, 0xcd, 0xff, 0xff],
        );
        assert_eq!(decode(&g16, &ROS), Ok(want.clone()));
        // 16-bit RGBA: 0xfdfd = 65021 is 253 in 8-bit units, so (255, 255, 253) averages to 254.33.
        let rgba16 = [
            [0u16, 0, 0, 9],
            [65535, 65535, 65021, 0],
            [52685, 52685, 52685, 1],
            [65535; 4],
        ];
        let rgba16: Vec<u8> = rgba16
            .iter()
            .flatten()
            .flat_map(|s| s.to_be_bytes())
            .collect();
        let rgba16 = png_bytes(2, 2, png::ColorType::Rgba, png::BitDepth::Sixteen, &rgba16);
        assert_eq!(decode(&rgba16, &ROS), Ok(want));
    }

    #[test]
    fn every_error_path_is_reported() {
        use ImageError::*;
        assert!(matches!(decode(b"GIF89a", &ROS), Err(UnknownFormat(_))));
        assert_eq!(decode(b"", &ROS), Err(UnknownFormat(vec![])));
        assert_eq!(
            decode(b"P6 1 1 255\n\0\0\0", &ROS),
            Err(UnsupportedMagic("P6".into()))
        );
        assert_eq!(
            decode(b"P5 3", &ROS),
            Err(MissingHeaderField { field: "height" })
        );
        assert!(matches!(
            decode(b"P5 3 x 255\n", &ROS),
            Err(BadHeaderNumber {
                field: "height",
                ..
            })
        ));
        assert_eq!(decode(b"P5 1 1 0\n\0", &ROS), Err(BadMaxval(0)));
        assert_eq!(decode(b"P5 1 1 65536\n\0", &ROS), Err(BadMaxval(65536)));
        assert_eq!(decode(b"P5 1 1 255", &ROS), Err(NoRasterSeparator));
        assert_eq!(
            decode(b"P5 0 1 255\n", &ROS),
            Err(Empty {
                width: 0,
                height: 1
            })
        );
        assert!(matches!(
            decode(b"P5 9000 9000 255\n", &ROS),
            Err(TooLarge { .. })
        ));
        assert_eq!(
            decode(b"P5 2 2 255\n\0\0\0", &ROS),
            Err(Truncated { got: 3, want: 4 })
        );
        assert_eq!(
            decode(b"P5 1 2 300\n\0\0\0", &ROS),
            Err(Truncated { got: 1, want: 2 })
        );
        assert_eq!(
            decode(b"P2 2 1 255\n7", &ROS),
            Err(Truncated { got: 1, want: 2 })
        );
        assert!(matches!(
            decode(b"P2 2 1 255\n7 x", &ROS),
            Err(BadSample { index: 1, .. })
        ));
        assert_eq!(
            decode(b"P2 1 1 9\n10", &ROS),
            Err(SampleAboveMax {
                index: 0,
                value: 10,
                maxval: 9
            })
        );
        assert_eq!(
            decode(b"P5 1 1 9\n\x0a", &ROS),
            Err(SampleAboveMax {
                index: 0,
                value: 10,
                maxval: 9
            })
        );
        let good = png_bytes(
            2,
            2,
            png::ColorType::Grayscale,
            png::BitDepth::Eight,
            &[0; 4],
        );
        assert!(matches!(
            decode(&good[..good.len() - 20], &ROS),
            Err(Png(_))
        ));
    }

    proptest! {
        #[test]
        fn decoding_arbitrary_bytes_never_panics(
            prefix in prop::sample::select(vec!["", "P5 ", "P2 ", "P5 4 3 255\n", "P5 2 2 65535\n", "P2 3 2 7\n", "\u{89}PNG"]),
            body in proptest::collection::vec(any::<u8>(), 0..64),
        ) {
            let bytes = if prefix == "\u{89}PNG" {
                [&[0x89u8, b'P', b'N', b'G', b'\r', b'\n', 0x1a, b'\n'][..], &body].concat()
            } else {
                [prefix.as_bytes(), &body].concat()
            };
            let _ = decode(&bytes, &ROS);
        }
    }
}
