//! Snapshots of the cost map: `map_server` files for robots and tools, and a picture
//! for people.
//!
//! * `<stem>.pgm` + `<stem>.yaml`: the cost map as a `map_server` map in `mode: raw`
//!   — each pixel is the cell's cost 0..100, 255 where no camera sees — so
//!   `map_server` (Nav2) loads exactly the grid that was published. Row 0 of the
//!   image is the grid's last row, as `map_server` expects.
//! * `<stem>.png`: the same for people: the floor plan (the `map_yaml` image, if
//!   any) or plain floor, hatched where no camera sees, each camera's coverage
//!   outlined in its own colour, the cost as a yellow-to-red overlay, the path
//!   segments outlined in blue, the cameras' zones dashed in olive, a caption
//!   above, and a labelled cost scale (0 to 100) and legend below (text in a 5×7
//!   bitmap font shipped in the binary, [`crate::font`]).
//!
//! The cost map bridge writes snapshots of the cost map now; `isochron costmap
//! snapshot --at HH:MM` writes the one the long-term model expects
//! (`Planner::expected_costmap`), with this same writer.
//!
//! Files are written under a temporary name and renamed, so a reader never sees
//! half a snapshot.

use std::io::Write;
use std::path::{Path, PathBuf};

use isochron_config::{CameraConfig, LoadedConfig};

use crate::font;
use crate::grid::{MapGrid, pgm_header};
use crate::homography::Homography;
use crate::raster::NOT_SEEN;

/// Why a floor plan could not be loaded or a snapshot written. Every message names
/// the file or directory.
#[derive(Debug, thiserror::Error)]
pub enum SnapshotError {
    /// The floor plan image cannot be read.
    #[error("cannot read {}: {source}", path.display())]
    Read {
        /// The image.
        path: PathBuf,
        /// What failed.
        source: std::io::Error,
    },
    /// A PGM whose header cannot be parsed.
    #[error("{}: damaged PGM header", path.display())]
    PgmHeader {
        /// The image.
        path: PathBuf,
    },
    /// A PGM that is not 8-bit, or shorter than its header says.
    #[error("{}: only complete 8-bit PGM files are supported", path.display())]
    PgmDepth {
        /// The image.
        path: PathBuf,
    },
    /// Neither a PGM nor a PNG.
    #[error("{}: not a PGM or PNG image: {source}", path.display())]
    NotAnImage {
        /// The image.
        path: PathBuf,
        /// What the PNG decoder said.
        source: png::DecodingError,
    },
    /// A PNG whose pixels cannot be decoded.
    #[error("{}: {source}", path.display())]
    Decode {
        /// The image.
        path: PathBuf,
        /// What the PNG decoder said.
        source: png::DecodingError,
    },
    /// The snapshot directory cannot be created.
    #[error("creating {}: {source}", dir.display())]
    CreateDir {
        /// The directory.
        dir: PathBuf,
        /// What failed.
        source: std::io::Error,
    },
    /// The snapshot directory cannot be listed.
    #[error("reading {}: {source}", dir.display())]
    ReadDir {
        /// The directory.
        dir: PathBuf,
        /// What failed.
        source: std::io::Error,
    },
    /// A snapshot file cannot be written.
    #[error("writing {}: {source}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// What failed.
        source: std::io::Error,
    },
    /// The picture cannot be encoded.
    #[error("{0}")]
    Encode(#[from] png::EncodingError),
}

/// A grey image of the floor plan, one value per grid cell, rows top (last grid
/// row) first — the layout of a `map_server` image.
#[derive(Debug, Clone, PartialEq)]
pub struct FloorPlan {
    /// Width, cells.
    pub width: u32,
    /// Height, cells.
    pub height: u32,
    /// Grey levels, row-major, top row first.
    pub grey: Vec<u8>,
}

impl FloorPlan {
    /// Loads a PGM (8-bit P5) or PNG (grey or colour, 8-bit) map image.
    pub fn load(path: &Path) -> Result<FloorPlan, SnapshotError> {
        let bytes = std::fs::read(path).map_err(|source| SnapshotError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        if bytes.starts_with(b"P5") {
            let h = pgm_header(&bytes).ok_or_else(|| SnapshotError::PgmHeader {
                path: path.to_path_buf(),
            })?;
            let n = h.width as usize * h.height as usize;
            if h.max == 0 || h.max > 255 || bytes.len() < h.data_offset + n {
                return Err(SnapshotError::PgmDepth {
                    path: path.to_path_buf(),
                });
            }
            let grey = bytes[h.data_offset..h.data_offset + n]
                .iter()
                .map(|&v| (v as u32 * 255 / h.max) as u8)
                .collect();
            return Ok(FloorPlan {
                width: h.width,
                height: h.height,
                grey,
            });
        }
        let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
        decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
        let mut reader = decoder
            .read_info()
            .map_err(|source| SnapshotError::NotAnImage {
                path: path.to_path_buf(),
                source,
            })?;
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader
            .next_frame(&mut buf)
            .map_err(|source| SnapshotError::Decode {
                path: path.to_path_buf(),
                source,
            })?;
        let channels = info.color_type.samples();
        let grey = buf[..info.buffer_size()]
            .chunks(channels)
            .map(|px| match channels {
                1 | 2 => px[0],
                _ => ((px[0] as u32 + px[1] as u32 + px[2] as u32) / 3) as u8,
            })
            .collect();
        Ok(FloorPlan {
            width: info.width,
            height: info.height,
            grey,
        })
    }
}

/// The `costmap.map_yaml` image as the snapshot's floor plan, if one is configured
/// and has the grid's size (one that cannot be read is warned about and left out).
pub fn floor_plan_of(loaded: &LoadedConfig, grid: Option<&MapGrid>) -> Option<FloorPlan> {
    let yaml = loaded.config.costmap.map_yaml.as_ref()?;
    let yaml = if yaml.is_absolute() {
        yaml.clone()
    } else {
        loaded.base_dir().join(yaml)
    };
    let text = std::fs::read_to_string(&yaml).ok()?;
    let image = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("image:"))
        .map(|s| s.trim().trim_matches(['"', '\'']).to_string())?;
    let image = yaml
        .parent()
        .unwrap_or(std::path::Path::new("."))
        .join(image);
    match FloorPlan::load(&image) {
        Ok(plan) if grid.is_some_and(|g| g.width == plan.width && g.height == plan.height) => {
            Some(plan)
        }
        Ok(_) => None,
        Err(e) => {
            tracing::warn!("the floor plan is left out of pictures: {e}");
            None
        }
    }
}

/// What a snapshot shows.
#[derive(Debug, Clone, Copy)]
pub struct Snapshot<'a> {
    /// The grid.
    pub grid: &'a MapGrid,
    /// Its cells (0..=100, -1 unknown), row-major from the origin.
    pub cells: &'a [i8],
    /// The floor plan under it, if one is configured and matches the grid.
    pub floor_plan: Option<&'a FloorPlan>,
    /// Per camera, the block covering each cell (or `NOT_SEEN`).
    pub coverage: &'a [&'a [u32]],
    /// Each camera's id, for the legend (as many as `coverage`).
    pub camera_ids: &'a [&'a str],
    /// Path segment outlines on the floor (map frame).
    pub segments: &'a [&'a [[f64; 2]]],
    /// Camera zones on the floor (map frame; see [`floor_zones`]).
    pub zones: &'a [Vec<[f64; 2]>],
    /// A title above the picture (empty: none).
    pub caption: &'a str,
    /// Time of the data, for the YAML's comment.
    pub stamp: &'a str,
}

/// The files a snapshot wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct SnapshotFiles {
    /// The `map_server` YAML.
    pub yaml: PathBuf,
    /// The raw-mode PGM.
    pub pgm: PathBuf,
    /// The picture.
    pub png: PathBuf,
}

/// Writes `<dir>/<stem>.{pgm,yaml,png}`.
pub fn write(dir: &Path, stem: &str, s: &Snapshot<'_>) -> Result<SnapshotFiles, SnapshotError> {
    std::fs::create_dir_all(dir).map_err(|source| SnapshotError::CreateDir {
        dir: dir.to_path_buf(),
        source,
    })?;
    let files = SnapshotFiles {
        yaml: dir.join(format!("{stem}.yaml")),
        pgm: dir.join(format!("{stem}.pgm")),
        png: dir.join(format!("{stem}.png")),
    };
    write_atomically(&files.pgm, &pgm_bytes(s.grid, s.cells))?;
    let yaml = map_yaml(s.grid, &format!("{stem}.pgm"), s.stamp);
    write_atomically(&files.png, &png_bytes(s)?)?;
    // The YAML last: once it exists, the image it names is complete.
    write_atomically(&files.yaml, yaml.as_bytes())?;
    Ok(files)
}

/// Removes the oldest snapshots in `dir` (by name: stems sort by time) beyond `keep`.
pub fn prune(dir: &Path, prefix: &str, keep: usize) -> Result<usize, SnapshotError> {
    let mut stems: Vec<String> = std::fs::read_dir(dir)
        .map_err(|source| SnapshotError::ReadDir {
            dir: dir.to_path_buf(),
            source,
        })?
        .filter_map(Result::ok)
        .filter_map(|e| e.file_name().into_string().ok())
        .filter(|n| n.starts_with(prefix) && n.ends_with(".yaml"))
        .map(|n| n.trim_end_matches(".yaml").to_string())
        .collect();
    stems.sort();
    let excess = stems.len().saturating_sub(keep);
    for stem in &stems[..excess] {
        for ext in ["yaml", "pgm", "png"] {
            let _ = std::fs::remove_file(dir.join(format!("{stem}.{ext}")));
        }
    }
    Ok(excess)
}

fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), SnapshotError> {
    let tmp = path.with_extension(format!(
        "{}.tmp-{}",
        path.extension().and_then(|e| e.to_str()).unwrap_or(""),
        std::process::id()
    ));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    result.map_err(|source| {
        let _ = std::fs::remove_file(&tmp);
        SnapshotError::Write {
            path: path.to_path_buf(),
            source,
        }
    })
}

/// The cost map as a binary PGM in `map_server` raw mode: value = cost, 255 =
/// unknown, top row = the grid's last row.
pub fn pgm_bytes(grid: &MapGrid, cells: &[i8]) -> Vec<u8> {
    let (w, h) = (grid.width as usize, grid.height as usize);
    let mut out = format!("P5\n# isochron activity cost map, map_server raw mode\n{w} {h}\n255\n")
        .into_bytes();
    out.reserve(w * h);
    for row in (0..h).rev() {
        for &c in &cells[row * w..(row + 1) * w] {
            out.push(if (0..=100).contains(&c) { c as u8 } else { 255 });
        }
    }
    out
}

/// The `map_server` YAML for `image`.
pub fn map_yaml(grid: &MapGrid, image: &str, stamp: &str) -> String {
    format!(
        "# isochron activity cost map at {stamp}: cost 0..100 per cell, 255 = no camera sees.\n\
         image: {image}\n\
         mode: raw\n\
         resolution: {}\n\
         origin: [{}, {}, {}]\n\
         negate: 0\n\
         occupied_thresh: 0.65\n\
         free_thresh: 0.25\n",
        grid.resolution, grid.origin_x, grid.origin_y, grid.yaw
    )
}

/// Distinct outline colours for up to 8 cameras (then they repeat).
const CAMERA_COLOURS: [[u8; 3]; 8] = [
    [0, 150, 136],
    [156, 39, 176],
    [255, 152, 0],
    [63, 81, 181],
    [121, 85, 72],
    [0, 188, 212],
    [233, 30, 99],
    [139, 195, 74],
];

/// Each camera's zones mapped onto the floor through its floor points (cameras
/// without floor points, and zone corners beyond the horizon, are left out).
pub fn floor_zones(cameras: &[CameraConfig]) -> Vec<Vec<[f64; 2]>> {
    let mut out = Vec::new();
    for cam in cameras {
        let Ok(Some((h, _))) = Homography::of_camera(cam) else {
            continue;
        };
        for zone in &cam.zones {
            let floor: Vec<[f64; 2]> = zone.polygon.iter().filter_map(|&p| h.apply(p)).collect();
            if floor.len() >= 3 {
                out.push(floor);
            }
        }
    }
    out
}

/// Colour of path segment outlines.
const SEGMENT_COLOUR: [u8; 3] = [30, 80, 220];
/// Colour of zone outlines (dashed).
const ZONE_COLOUR: [u8; 3] = [128, 128, 0];
/// Colour of text.
const INK: [u8; 3] = [20, 20, 20];

/// An RGB picture being drawn.
struct Canvas {
    w: usize,
    h: usize,
    rgb: Vec<u8>,
}

impl Canvas {
    fn put(&mut self, x: usize, y: usize, c: [u8; 3]) {
        if x < self.w && y < self.h {
            let k = (y * self.w + x) * 3;
            self.rgb[k..k + 3].copy_from_slice(&c);
        }
    }

    fn fill(&mut self, x: usize, y: usize, w: usize, h: usize, c: [u8; 3]) {
        for yy in y..y + h {
            for xx in x..x + w {
                self.put(xx, yy, c);
            }
        }
    }

    fn text(&mut self, x: usize, y: usize, text: &str, scale: usize) {
        font::draw(&mut self.rgb, self.w, x, y, text, scale, INK);
    }

    /// A closed outline, 2 px wide; `dash` draws every other 6 px only.
    fn outline(
        &mut self,
        points: &[(f64, f64)],
        top: usize,
        bottom: usize,
        c: [u8; 3],
        dash: bool,
    ) {
        for k in 0..points.len() {
            let (a, b) = (points[k], points[(k + 1) % points.len()]);
            let steps =
                ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).clamp(1, 100_000);
            for t in 0..=steps {
                if dash && (t / 6) % 2 == 1 {
                    continue;
                }
                let f = t as f64 / steps as f64;
                let (x, y) = (a.0 + (b.0 - a.0) * f, a.1 + (b.1 - a.1) * f);
                if x >= 0.0 && y >= top as f64 && (y as usize) < bottom {
                    for d in 0..2 {
                        self.put(x as usize + d, y as usize, c);
                        self.put(x as usize, y as usize + d, c);
                    }
                }
            }
        }
    }
}

/// Left edge of the cost scale and the legend, picture pixels.
const LEFT: usize = 8;

/// Where things go in a snapshot's picture, pixels.
struct Layout {
    /// Grid cells across.
    w: usize,
    /// Grid cells down.
    h: usize,
    /// Picture pixels per cell.
    scale: usize,
    /// Picture width.
    iw: usize,
    /// Text scale: 2 on wide pictures, else 1.
    ts: usize,
    /// Height of a line of text.
    line: usize,
    /// Top of the map (below the caption).
    top: usize,
    /// Bottom of the map.
    map_bottom: usize,
}

/// `text` in lines of at most `columns` characters, broken at spaces (a word
/// longer than a line is cut); none for an empty text.
fn wrapped(text: &str, columns: usize) -> Vec<String> {
    let columns = columns.max(1);
    let mut lines: Vec<String> = Vec::new();
    for word in text.split_whitespace() {
        let word: String = word.chars().take(columns).collect();
        match lines.last_mut() {
            Some(last) if last.chars().count() + 1 + word.chars().count() <= columns => {
                last.push(' ');
                last.push_str(&word);
            }
            _ => lines.push(word),
        }
    }
    lines
}

/// The picture for people, as PNG bytes.
pub fn png_bytes(s: &Snapshot<'_>) -> Result<Vec<u8>, SnapshotError> {
    let (w, h) = (s.grid.width as usize, s.grid.height as usize);
    let scale = (900 / w.max(h).max(1)).clamp(1, 8);
    let iw = (w * scale).max(240);
    // Text at twice the font's size on wide pictures.
    let ts = if iw >= 480 { 2 } else { 1 };
    let line = (font::HEIGHT + 3) * ts;
    let caption = wrapped(s.caption, (iw - 8) / (font::ADVANCE * ts));
    let top = if caption.is_empty() {
        0
    } else {
        caption.len() * line + 6
    };
    let map_bottom = top + h * scale;
    let l = Layout {
        w,
        h,
        scale,
        iw,
        ts,
        line,
        top,
        map_bottom,
    };
    // Below the map: the colour bar, its labels, the legend.
    let ih = map_bottom + 6 + 12 + 4 + line + 4 + line + 4;
    let mut img = Canvas {
        w: iw,
        h: ih,
        rgb: vec![255u8; iw * ih * 3],
    };
    draw_cells(&mut img, s, &l);
    draw_coverage(&mut img, s, &l);
    draw_outlines(&mut img, s, &l);
    for (i, text) in caption.iter().enumerate() {
        img.text(4, 4 + i * line, text, ts);
    }
    let legend_y = draw_cost_scale(&mut img, &l);
    draw_legend(&mut img, s, &l, legend_y);
    let mut out = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut out, iw as u32, ih as u32);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header()?;
        writer.write_image_data(&img.rgb)?;
    }
    Ok(out)
}

/// The cells: their cost over the floor plan (or plain floor), hatched where no
/// camera sees.
fn draw_cells(img: &mut Canvas, s: &Snapshot<'_>, l: &Layout) {
    let (w, h, scale) = (l.w, l.h, l.scale);
    let plan = s
        .floor_plan
        .filter(|p| p.width as usize == w && p.height as usize == h);
    for gy in 0..h {
        // Image row 0 is the grid's last row.
        let py0 = l.top + (h - 1 - gy) * scale;
        for gx in 0..w {
            let k = gy * w + gx;
            let base = match plan {
                Some(p) => {
                    let g = p.grey[(h - 1 - gy) * w + gx];
                    // Lighten the plan so the overlay stays readable.
                    let g = 128 + g / 2;
                    [g, g, g]
                }
                None => [250, 250, 250],
            };
            let cost = s.cells.get(k).copied().unwrap_or(-1);
            for dy in 0..scale {
                for dx in 0..scale {
                    let c = if cost < 0 {
                        hatch(gx * scale + dx + gy * scale + dy, base)
                    } else {
                        cost_colour(base, cost as u8)
                    };
                    img.put(gx * scale + dx, py0 + dy, c);
                }
            }
        }
    }
}

/// Camera coverage outlines: seen cells with an unseen 4-neighbour.
fn draw_coverage(img: &mut Canvas, s: &Snapshot<'_>, l: &Layout) {
    let (w, h, scale) = (l.w, l.h, l.scale);
    for (n, cover) in s.coverage.iter().enumerate() {
        if cover.len() != w * h {
            continue;
        }
        let colour = CAMERA_COLOURS[n % CAMERA_COLOURS.len()];
        let seen = |x: isize, y: isize| {
            x >= 0
                && y >= 0
                && (x as usize) < w
                && (y as usize) < h
                && cover[y as usize * w + x as usize] != NOT_SEEN
        };
        for gy in 0..h as isize {
            for gx in 0..w as isize {
                if seen(gx, gy)
                    && !(seen(gx - 1, gy)
                        && seen(gx + 1, gy)
                        && seen(gx, gy - 1)
                        && seen(gx, gy + 1))
                {
                    let py0 = l.top + (h - 1 - gy as usize) * scale;
                    img.fill(gx as usize * scale, py0, scale, scale, colour);
                }
            }
        }
    }
}

/// Zone and segment outlines.
fn draw_outlines(img: &mut Canvas, s: &Snapshot<'_>, l: &Layout) {
    // In picture pixels.
    let to_px = |p: &[f64; 2]| {
        let g = s.grid.to_grid(*p);
        (
            g[0] * l.scale as f64,
            l.top as f64 + (l.h as f64 - g[1]) * l.scale as f64,
        )
    };
    for zone in s.zones {
        let points: Vec<(f64, f64)> = zone.iter().map(to_px).collect();
        img.outline(&points, l.top, l.map_bottom, ZONE_COLOUR, true);
    }
    for poly in s.segments {
        let points: Vec<(f64, f64)> = poly.iter().map(to_px).collect();
        img.outline(&points, l.top, l.map_bottom, SEGMENT_COLOUR, false);
    }
}

/// The cost scale below the map: 0 (left) to 100 (right), labelled every 25.
/// Returns the top of the legend below it.
fn draw_cost_scale(img: &mut Canvas, l: &Layout) -> usize {
    let (iw, ts) = (l.iw, l.ts);
    let bar_y = l.map_bottom + 6;
    let (x0, bar_w) = (LEFT, iw - 2 * LEFT);
    for x in 0..bar_w {
        let cost = (x * 100 / bar_w.max(1)) as u8;
        img.fill(
            x0 + x,
            bar_y,
            1,
            12,
            cost_colour([250, 250, 250], cost.max(1)),
        );
    }
    let label_y = bar_y + 12 + 4;
    for v in [0usize, 25, 50, 75, 100] {
        let label = if v == 0 {
            "COST 0".to_string()
        } else {
            v.to_string()
        };
        let x = x0 + v * (bar_w - 1) / 100;
        img.fill(x, bar_y + 12, 1, 3, INK);
        let lw = font::width(&label, ts);
        let lx = if v == 0 {
            x0
        } else {
            (x + 1)
                .saturating_sub(lw)
                .max(x.saturating_sub(lw / 2))
                .min(iw - lw)
        };
        img.text(lx, label_y, &label, ts);
    }
    label_y + l.line + 4
}

/// The legend at `legend_y`: what the outlines and the hatching mean.
fn draw_legend(img: &mut Canvas, s: &Snapshot<'_>, l: &Layout, legend_y: usize) {
    let ts = l.ts;
    let mut x = LEFT;
    let swatch = font::HEIGHT * ts;
    let mut entry = |colour: Option<[u8; 3]>, label: &str| {
        match colour {
            Some(c) => img.fill(x, legend_y, swatch, swatch, c),
            None => {
                for dy in 0..swatch {
                    for dx in 0..swatch {
                        img.put(x + dx, legend_y + dy, hatch(dx + dy, [250, 250, 250]));
                    }
                }
            }
        }
        img.text(x + swatch + 3, legend_y, label, ts);
        x += swatch + 3 + font::width(label, ts) + 4 * ts;
    };
    entry(None, "UNSEEN");
    if !s.segments.is_empty() {
        entry(Some(SEGMENT_COLOUR), "SEGMENT");
    }
    if !s.zones.is_empty() {
        entry(Some(ZONE_COLOUR), "ZONE");
    }
    for (n, id) in s.camera_ids.iter().enumerate() {
        entry(Some(CAMERA_COLOURS[n % CAMERA_COLOURS.len()]), id);
    }
}

/// The hatching of cells no camera sees, at diagonal position `d`.
fn hatch(d: usize, base: [u8; 3]) -> [u8; 3] {
    if d % 6 < 2 {
        [150, 150, 150]
    } else {
        blend(base, [200, 200, 200], 0.5)
    }
}

/// A cell's colour: the base for cost 0, then yellow to red as the cost rises.
fn cost_colour(base: [u8; 3], cost: u8) -> [u8; 3] {
    if cost == 0 {
        return base;
    }
    let f = cost.min(100) as f64 / 100.0;
    let ramp = [255u8, (230.0 * (1.0 - f)) as u8, 0];
    blend(base, ramp, 0.35 + 0.65 * f)
}

fn blend(a: [u8; 3], b: [u8; 3], t: f64) -> [u8; 3] {
    [0, 1, 2].map(|k| (a[k] as f64 * (1.0 - t) + b[k] as f64 * t).round() as u8)
}

#[cfg(test)]
mod tests;
