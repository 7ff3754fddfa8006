//! Shared helpers of the output-layer tests: a synthetic cell, deterministic noise, PNG
//! decoding.
#![allow(dead_code)]

use std::path::Path;

use visco::output::{Grid, Map};

/// Deterministic noise in [−1, 1] from a seed and a pixel.
pub fn noise(seed: u64, i: usize, j: usize) -> f64 {
    let mut z = seed
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((i as u64) << 32 | j as u64);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// A cell-like sample on 50 × 50 elements over 5 × 5 µm: a dome with a nucleus (h up to
/// 0.3 µm), c in 4–8 ×10⁻⁷ N·s/m and k in 2–5 ×10⁻³ N/m.
pub fn cell() -> (Map, Map, Map) {
    let g = Grid::covering(50, 50, 0.05e-6, 0.05e-6, 0.1e-6, 0.1e-6);
    let (cx, cy, r) = (2.4e-6, 2.6e-6, 2.0e-6);
    let (nx, ny, nr) = (2.8e-6, 2.3e-6, 0.7e-6);
    let dome = move |x: f64, y: f64| {
        let q = ((x - cx).powi(2) + (y - cy).powi(2) * 1.2) / (r * r);
        (1.0 - q).max(0.0).sqrt()
    };
    let nucleus = move |x: f64, y: f64| (-((x - nx).powi(2) + (y - ny).powi(2)) / (nr * nr)).exp();
    let h = Map::from_fn(g, "h", "m", |x, y| {
        let d = dome(x, y);
        0.19e-6 * d
            + if d > 0.0 {
                0.11e-6 * nucleus(x, y) * d.sqrt()
            } else {
                0.0
            }
    });
    let c = Map::from_fn(g, "c", "N·s/m", |x, y| {
        let d = dome(x, y);
        4e-7 + if d > 0.0 {
            1.2e-7 + 2.8e-7 * nucleus(x, y) + 0.3e-7 * (x * 3e6).sin()
        } else {
            0.0
        }
    });
    let k = Map::from_fn(g, "k", "N/m", |x, y| {
        let d = dome(x, y);
        2e-3 + if d > 0.0 {
            0.8e-3 + 2.2e-3 * nucleus(x, y) * d
        } else {
            0.0
        }
    });
    (h, c, k)
}

/// A decoded 8-bit RGB PNG.
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

impl Image {
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        let k = ((y * self.width + x) * 3) as usize;
        [self.rgb[k], self.rgb[k + 1], self.rgb[k + 2]]
    }

    pub fn distinct_colors(&self) -> usize {
        let mut set = std::collections::HashSet::new();
        for p in self.rgb.chunks_exact(3) {
            set.insert([p[0], p[1], p[2]]);
        }
        set.len()
    }

    pub fn has_color(&self, c: [u8; 3]) -> bool {
        self.rgb.chunks_exact(3).any(|p| p == c)
    }

    /// Variance of the grey level over all pixels.
    pub fn variance(&self) -> f64 {
        let n = (self.width * self.height) as f64;
        let g: Vec<f64> = self
            .rgb
            .chunks_exact(3)
            .map(|p| (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0)
            .collect();
        let m = g.iter().sum::<f64>() / n;
        g.iter().map(|v| (v - m).powi(2)).sum::<f64>() / n
    }
}

/// Decodes a PNG written by the figures (8-bit RGB), panicking with the path on failure.
pub fn decode_png(path: &Path) -> Image {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let dec = png::Decoder::new(std::io::BufReader::new(file));
    let mut reader = dec
        .read_info()
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb, "{}", path.display());
    assert_eq!(info.bit_depth, png::BitDepth::Eight, "{}", path.display());
    buf.truncate(info.buffer_size());
    Image {
        width: info.width,
        height: info.height,
        rgb: buf,
    }
}
