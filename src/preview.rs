//! 8-bit previews of linear radiance: tone mapping, crops and PNG grids for
//! the quality report.

use std::path::Path;

use crate::error::Error;

/// An 8-bit RGB image.
pub struct Rgb8 {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Row-major RGB bytes.
    pub data: Vec<u8>,
}

/// Linear radiance to display: `x / (1 + x)` (Reinhard) then sRGB gamma.
pub fn tonemap(v: f32, exposure: f32) -> u8 {
    let x = (v * exposure).max(0.0);
    let x = if x.is_finite() { x / (1.0 + x) } else { 1.0 };
    let s = if x <= 0.003_130_8 { 12.92 * x } else { 1.055 * x.powf(1.0 / 2.4) - 0.055 };
    (s * 255.0 + 0.5).clamp(0.0, 255.0) as u8
}

impl Rgb8 {
    /// A crop `(x, y, w, h)` of three row-major channel slices of width `stride`.
    pub fn from_channels(ch: [&[f32]; 3], stride: usize, crop: (usize, usize, usize, usize), exposure: f32) -> Rgb8 {
        let (x0, y0, w, h) = crop;
        let mut data = Vec::with_capacity(w * h * 3);
        for y in y0..y0 + h {
            for x in x0..x0 + w {
                for c in ch {
                    data.push(tonemap(c[y * stride + x], exposure));
                }
            }
        }
        Rgb8 { width: w, height: h, data }
    }

    /// Images side by side with a `gap`-pixel white border between them.
    pub fn hstack(images: &[Rgb8], gap: usize) -> Rgb8 {
        let height = images.iter().map(|i| i.height).max().unwrap_or(0);
        let width = images.iter().map(|i| i.width).sum::<usize>() + gap * images.len().saturating_sub(1);
        let mut data = vec![255u8; width * height * 3];
        let mut x0 = 0;
        for img in images {
            for y in 0..img.height {
                let dst = (y * width + x0) * 3;
                data[dst..dst + img.width * 3].copy_from_slice(&img.data[y * img.width * 3..(y + 1) * img.width * 3]);
            }
            x0 += img.width + gap;
        }
        Rgb8 { width, height, data }
    }

    /// Images stacked vertically with a `gap`-pixel white border between them.
    pub fn vstack(images: &[Rgb8], gap: usize) -> Rgb8 {
        let width = images.iter().map(|i| i.width).max().unwrap_or(0);
        let height = images.iter().map(|i| i.height).sum::<usize>() + gap * images.len().saturating_sub(1);
        let mut data = vec![255u8; width * height * 3];
        let mut y0 = 0;
        for img in images {
            for y in 0..img.height {
                let dst = ((y0 + y) * width) * 3;
                data[dst..dst + img.width * 3].copy_from_slice(&img.data[y * img.width * 3..(y + 1) * img.width * 3]);
            }
            y0 += img.height + gap;
        }
        Rgb8 { width, height, data }
    }

    /// Write as PNG.
    pub fn write_png(&self, path: &Path) -> Result<(), Error> {
        let io = |e: std::io::Error| Error::Io { path: path.to_path_buf(), source: e };
        let file = std::fs::File::create(path).map_err(io)?;
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), self.width as u32, self.height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header().map_err(|e| io(std::io::Error::other(e)))?;
        w.write_image_data(&self.data).map_err(|e| io(std::io::Error::other(e)))?;
        Ok(())
    }
}
