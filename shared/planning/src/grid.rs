//! The map grid: where each cell of the cost map lies in the robots' map frame.
//!
//! Cell `(i, j)` (column `i`, row `j`, row-major index `j·width + i`) covers the
//! square whose corner is `origin + R(yaw)·(i·res, j·res)` — the convention of
//! `nav_msgs/MapMetaData`, so row 0 is at the origin (the *bottom* of a
//! `map_server` image). A grid comes from the `[costmap]` keys or from a
//! `map_server` YAML file ([`MapGrid::from_map_yaml`]), so the activity lines up
//! with the robots' own map.

use std::path::{Path, PathBuf};

use isochron_config::{CostmapConfig, LoadedConfig, MAX_GRID_CELLS};
use serde::Deserialize;

/// A point `[x, y]` in the map frame, metres.
pub type Point = [f64; 2];

/// The grid's geometry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapGrid {
    /// x of cell (0, 0)'s corner, metres.
    pub origin_x: f64,
    /// y of cell (0, 0)'s corner, metres.
    pub origin_y: f64,
    /// Rotation of the grid about z, radians.
    pub yaw: f64,
    /// Cell edge, metres.
    pub resolution: f64,
    /// Cells per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
}

/// Why the grid cannot be set up; `key` is the config key to fix.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {message}")]
pub struct GridError {
    /// Config key.
    pub key: String,
    /// What is wrong.
    pub message: String,
}

impl GridError {
    fn new(key: &str, message: impl Into<String>) -> Self {
        GridError {
            key: key.into(),
            message: message.into(),
        }
    }
}

/// The part of a `map_server` YAML the grid needs (other keys are ignored).
#[derive(Debug, Clone, Deserialize)]
struct MapYaml {
    image: PathBuf,
    resolution: f64,
    origin: Vec<f64>,
}

impl MapGrid {
    /// The grid of `[costmap]`, or `None` when none is configured.
    pub fn from_config(loaded: &LoadedConfig) -> Result<Option<MapGrid>, GridError> {
        let c: &CostmapConfig = &loaded.config.costmap;
        if let Some(yaml) = &c.map_yaml {
            let path = if yaml.is_absolute() {
                yaml.clone()
            } else {
                loaded.base_dir().join(yaml)
            };
            return MapGrid::from_map_yaml(&path).map(Some);
        }
        let (Some(width), Some(height)) = (c.width_cells, c.height_cells) else {
            return Ok(None);
        };
        Ok(Some(MapGrid {
            origin_x: c.origin_x_m.unwrap_or(0.0),
            origin_y: c.origin_y_m.unwrap_or(0.0),
            yaw: c.origin_yaw_rad.unwrap_or(0.0),
            resolution: c.resolution_m.unwrap_or(0.1),
            width,
            height,
        }))
    }

    /// The grid of a `map_server` map: `resolution` and `origin: [x, y, yaw]` from
    /// the YAML, width and height from its image (PGM or PNG).
    pub fn from_map_yaml(path: &Path) -> Result<MapGrid, GridError> {
        const KEY: &str = "costmap.map_yaml";
        let text = std::fs::read_to_string(path)
            .map_err(|e| GridError::new(KEY, format!("cannot read {}: {e}", path.display())))?;
        let yaml: MapYaml = serde_norway::from_str(&text).map_err(|e| {
            GridError::new(
                KEY,
                format!(
                    "{} is not a map_server YAML (image, resolution, origin: [x, y, yaw]): {e}",
                    path.display()
                ),
            )
        })?;
        if !(yaml.resolution.is_finite() && yaml.resolution > 0.0) {
            return Err(GridError::new(
                KEY,
                format!("{}: resolution must be > 0", path.display()),
            ));
        }
        if yaml.origin.len() != 3 || yaml.origin.iter().any(|v| !v.is_finite()) {
            return Err(GridError::new(
                KEY,
                format!(
                    "{}: origin must be [x, y, yaw], found {:?}",
                    path.display(),
                    yaml.origin
                ),
            ));
        }
        let image = if yaml.image.is_absolute() {
            yaml.image.clone()
        } else {
            path.parent().unwrap_or(Path::new(".")).join(&yaml.image)
        };
        let (width, height) = image_size(&image).map_err(|e| GridError::new(KEY, e.to_string()))?;
        let grid = MapGrid {
            origin_x: yaml.origin[0],
            origin_y: yaml.origin[1],
            yaw: yaml.origin[2],
            resolution: yaml.resolution,
            width,
            height,
        };
        if grid.len() as u64 > MAX_GRID_CELLS {
            return Err(GridError::new(
                KEY,
                format!(
                    "the map is {width}x{height} cells; at most {MAX_GRID_CELLS} fit one grid message: give a coarser map (e.g. resample the image and scale resolution)"
                ),
            ));
        }
        Ok(grid)
    }

    /// Number of cells.
    pub fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// True if the grid has no cells.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Map-frame point of grid coordinates `(gx, gy)` (in cells, fractional).
    pub fn to_map(&self, gx: f64, gy: f64) -> Point {
        let (s, c) = self.yaw.sin_cos();
        let (dx, dy) = (gx * self.resolution, gy * self.resolution);
        [
            self.origin_x + c * dx - s * dy,
            self.origin_y + s * dx + c * dy,
        ]
    }

    /// Grid coordinates (in cells, fractional) of a map-frame point.
    pub fn to_grid(&self, p: Point) -> [f64; 2] {
        let (s, c) = self.yaw.sin_cos();
        let (dx, dy) = (p[0] - self.origin_x, p[1] - self.origin_y);
        [
            (c * dx + s * dy) / self.resolution,
            (-s * dx + c * dy) / self.resolution,
        ]
    }

    /// Centre of cell `(i, j)` in the map frame.
    pub fn cell_center(&self, i: u32, j: u32) -> Point {
        self.to_map(i as f64 + 0.5, j as f64 + 0.5)
    }

    /// The cell containing `p`, if inside the grid.
    pub fn cell_of(&self, p: Point) -> Option<(u32, u32)> {
        let [gx, gy] = self.to_grid(p);
        (gx >= 0.0 && gy >= 0.0 && gx < self.width as f64 && gy < self.height as f64)
            .then_some((gx as u32, gy as u32))
    }

    /// Row-major index of cell `(i, j)`.
    pub fn index(&self, i: u32, j: u32) -> usize {
        j as usize * self.width as usize + i as usize
    }

    /// Indices of the cells whose centre lies inside the convex or concave polygon
    /// `poly` (map frame), visiting only the polygon's bounding box.
    pub fn cells_in(&self, poly: &[Point]) -> Vec<usize> {
        let mut out = Vec::new();
        let Some((i0, j0, i1, j1)) = self.bounds_of(poly) else {
            return out;
        };
        for j in j0..=j1 {
            for i in i0..=i1 {
                if isochron_wire::geometry::point_in_polygon(self.cell_center(i, j), poly) {
                    out.push(self.index(i, j));
                }
            }
        }
        out
    }

    /// The inclusive cell range `(i0, j0, i1, j1)` covering `pts`, clipped to the
    /// grid; `None` if it misses the grid.
    pub fn bounds_of(&self, pts: &[Point]) -> Option<(u32, u32, u32, u32)> {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for p in pts {
            let g = self.to_grid(*p);
            for k in 0..2 {
                lo[k] = lo[k].min(g[k]);
                hi[k] = hi[k].max(g[k]);
            }
        }
        if !(lo[0].is_finite() && lo[1].is_finite() && hi[0].is_finite() && hi[1].is_finite()) {
            return None;
        }
        let (w, h) = (self.width as f64, self.height as f64);
        if hi[0] < 0.0 || hi[1] < 0.0 || lo[0] >= w || lo[1] >= h {
            return None;
        }
        let clip = |v: f64, n: f64| v.floor().clamp(0.0, n - 1.0) as u32;
        Some((
            clip(lo[0], w),
            clip(lo[1], h),
            clip(hi[0], w),
            clip(hi[1], h),
        ))
    }
}

/// Why [`image_size`] cannot tell an image's size.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file cannot be read.
    #[error("cannot read {}: {source}", path.display())]
    Read {
        /// The image.
        path: PathBuf,
        /// What reading said.
        source: std::io::Error,
    },
    /// A PGM whose header does not parse.
    #[error("{}: damaged PGM header", .0.display())]
    DamagedPgm(PathBuf),
    /// Neither PGM nor PNG.
    #[error(
        "{}: the map image must be PGM or PNG (set the grid keys instead of map_yaml for other formats)",
        .0.display()
    )]
    Format(PathBuf),
}

/// Width and height of a PGM (P2/P5) or PNG image, from its header.
pub fn image_size(path: &Path) -> Result<(u32, u32), ImageError> {
    let bytes = std::fs::read(path).map_err(|source| ImageError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") && bytes.len() >= 24 {
        let w = u32::from_be_bytes([bytes[16], bytes[17], bytes[18], bytes[19]]);
        let h = u32::from_be_bytes([bytes[20], bytes[21], bytes[22], bytes[23]]);
        return Ok((w, h));
    }
    if bytes.starts_with(b"P5") || bytes.starts_with(b"P2") {
        let header =
            pgm_header(&bytes).ok_or_else(|| ImageError::DamagedPgm(path.to_path_buf()))?;
        return Ok((header.width, header.height));
    }
    Err(ImageError::Format(path.to_path_buf()))
}

/// A parsed PGM header.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PgmHeader {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Largest value.
    pub max: u32,
    /// Offset of the first pixel (binary P5).
    pub data_offset: usize,
}

/// Parses the header of a PGM file (magic, width, height, maxval; `#` comments).
pub fn pgm_header(bytes: &[u8]) -> Option<PgmHeader> {
    let mut fields = Vec::with_capacity(4);
    let mut i = 0;
    while fields.len() < 4 && i < bytes.len() {
        match bytes[i] {
            b'#' => {
                while i < bytes.len() && bytes[i] != b'\n' {
                    i += 1;
                }
            }
            c if c.is_ascii_whitespace() => i += 1,
            _ => {
                let start = i;
                while i < bytes.len() && !bytes[i].is_ascii_whitespace() {
                    i += 1;
                }
                fields.push(std::str::from_utf8(&bytes[start..i]).ok()?.to_string());
            }
        }
    }
    if fields.len() < 4 || !(fields[0] == "P5" || fields[0] == "P2") {
        return None;
    }
    Some(PgmHeader {
        width: fields[1].parse().ok()?,
        height: fields[2].parse().ok()?,
        max: fields[3].parse().ok()?,
        // One whitespace byte separates the header from the pixels.
        data_offset: i + 1,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_and_points_agree_with_yaw() {
        let g = MapGrid {
            origin_x: 1.0,
            origin_y: 2.0,
            yaw: std::f64::consts::FRAC_PI_2,
            resolution: 0.5,
            width: 4,
            height: 3,
        };
        // With yaw 90°, the grid's x axis points along the map's +y.
        let c = g.cell_center(0, 0);
        assert!(
            (c[0] - 0.75).abs() < 1e-12 && (c[1] - 2.25).abs() < 1e-12,
            "{c:?}"
        );
        assert_eq!(g.cell_of(g.cell_center(3, 2)), Some((3, 2)));
        assert_eq!(g.cell_of([5.0, 5.0]), None);
        assert_eq!(g.index(3, 2), 11);
    }

    #[test]
    fn polygon_cells_are_those_with_centres_inside() {
        let g = MapGrid {
            origin_x: 0.0,
            origin_y: 0.0,
            yaw: 0.0,
            resolution: 1.0,
            width: 10,
            height: 10,
        };
        let square = [[2.0, 3.0], [4.0, 3.0], [4.0, 5.0], [2.0, 5.0]];
        let cells = g.cells_in(&square);
        assert_eq!(
            cells,
            vec![g.index(2, 3), g.index(3, 3), g.index(2, 4), g.index(3, 4)]
        );
        // Partly outside: clipped, no panic.
        assert_eq!(
            g.cells_in(&[[-5.0, -5.0], [0.9, -5.0], [0.9, 0.9], [-5.0, 0.9]]),
            vec![0]
        );
        assert!(
            g.cells_in(&[[20.0, 20.0], [21.0, 20.0], [21.0, 21.0]])
                .is_empty()
        );
    }

    #[test]
    fn map_yaml_gives_origin_resolution_and_image_size() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("site.pgm"),
            b"P5\n# made by a test\n7 5\n255\n",
        )
        .unwrap();
        std::fs::write(
            dir.path().join("site.yaml"),
            "image: site.pgm\nresolution: 0.05\norigin: [-3.5, 2.0, 0.1]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
        )
        .unwrap();
        let g = MapGrid::from_map_yaml(&dir.path().join("site.yaml")).unwrap();
        assert_eq!(
            g,
            MapGrid {
                origin_x: -3.5,
                origin_y: 2.0,
                yaw: 0.1,
                resolution: 0.05,
                width: 7,
                height: 5
            }
        );
        std::fs::write(
            dir.path().join("bad.yaml"),
            "image: site.pgm\nresolution: 0.05\norigin: [1, 2]\n",
        )
        .unwrap();
        let err = MapGrid::from_map_yaml(&dir.path().join("bad.yaml")).unwrap_err();
        assert_eq!(err.key, "costmap.map_yaml");
        assert!(err.message.contains("[x, y, yaw]"), "{err}");
        std::fs::write(
            dir.path().join("j.yaml"),
            "image: x.jpg\nresolution: 1\norigin: [0, 0, 0]\n",
        )
        .unwrap();
        std::fs::write(dir.path().join("x.jpg"), b"\xff\xd8\xff").unwrap();
        assert!(MapGrid::from_map_yaml(&dir.path().join("j.yaml")).is_err());
    }
}
