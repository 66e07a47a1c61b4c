//! The calibration overlay of `isochron costmap check --overlay OUT.png`: one frame
//! of a camera with everything the configuration says about its view drawn on it —
//! the block grid, mask polygons, zones, the floor grid (1 m lines) and the route
//! segments projected through the floor homography, and each calibration point
//! with where the fit puts it back. A wrong tape mark shows as a point whose
//! projected floor point lies away from it, and the floor grid bends wrong.

use std::path::Path;

use anyhow::{Context, bail};
use isochron_config::{Polygon as PixelPolygon, ZoneConfig};
use isochron_planning::calibration::Calibration;
use isochron_planning::homography::Point;
use opencv::core::{Mat, Size};
use opencv::prelude::*;
use opencv::{imgproc, videoio};
use plotters::prelude::*;

/// One frame, RGB, 8 bits per channel, row-major.
pub struct Frame {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `width * height * 3` bytes.
    pub rgb: Vec<u8>,
}

impl Frame {
    /// The first frame of a video, or an image file, scaled to `size` (the camera's
    /// analysis size, where masks, zones and floor points are given) when set.
    pub fn read(path: &Path, size: Option<(u32, u32)>) -> anyhow::Result<Frame> {
        if !path.is_file() {
            bail!("--frame {}: no such file", path.display());
        }
        // OpenCV logs every backend it tries on a file it cannot read; the one line
        // below says it all.
        let _ = opencv::core::set_log_level(opencv::core::LogLevel::LOG_LEVEL_SILENT);
        let mut cap = videoio::VideoCapture::from_file(path.as_os_str(), videoio::CAP_ANY)
            .with_context(|| format!("opening {}", path.display()))?;
        let mut bgr = Mat::default();
        if !cap.is_opened()? || !cap.read(&mut bgr)? || bgr.empty() {
            bail!("{}: not a video or image OpenCV can decode", path.display());
        }
        if let Some((w, h)) = size
            && (w as i32, h as i32) != (bgr.cols(), bgr.rows())
        {
            let mut scaled = Mat::default();
            imgproc::resize(
                &bgr,
                &mut scaled,
                Size::new(w as i32, h as i32),
                0.0,
                0.0,
                imgproc::INTER_AREA,
            )?;
            bgr = scaled;
        }
        let mut rgb = Mat::default();
        let code = match bgr.channels() {
            1 => imgproc::COLOR_GRAY2RGB,
            4 => imgproc::COLOR_BGRA2RGB,
            _ => imgproc::COLOR_BGR2RGB,
        };
        imgproc::cvt_color(&bgr, &mut rgb, code, 0)?;
        let rgb = if rgb.is_continuous() {
            rgb
        } else {
            rgb.try_clone()?
        };
        Ok(Frame {
            width: rgb.cols() as u32,
            height: rgb.rows() as u32,
            rgb: rgb.data_bytes()?.to_vec(),
        })
    }
}

/// A floor polygon with a name (a route segment).
pub struct FloorPolygon {
    /// Label.
    pub name: String,
    /// Outline, metres.
    pub polygon_m: Vec<Point>,
}

/// What the overlay shows of one camera.
pub struct Scene<'a> {
    /// Camera id, for the legend.
    pub camera: &'a str,
    /// Block edge, pixels.
    pub block_px: u32,
    /// Mask polygons, pixels.
    pub masks: &'a [PixelPolygon],
    /// Zones, pixels.
    pub zones: &'a [ZoneConfig],
    /// The floor mapping and its residuals, if the camera has floor points.
    pub calibration: Option<&'a Calibration>,
    /// Floor area to draw the 1 m grid over: `[min, max]` corners, metres.
    pub floor_extent: Option<[Point; 2]>,
    /// Route segments on the floor.
    pub segments: &'a [FloorPolygon],
}

/// Where the overlay is drawn, and the error drawing on it gives.
type Area<DB> = DrawingArea<DB, plotters::coord::Shift>;
type Drawn<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// Draws `scene` over `frame` into the PNG `out`.
pub fn draw(out: &Path, frame: &Frame, scene: &Scene) -> anyhow::Result<()> {
    crate::font::load()?;
    let (w, h) = (frame.width, frame.height);
    let mut backend = BitMapBackend::new(out, (w, h));
    backend
        .blit_bitmap((0, 0), (w, h), &frame.rgb)
        .map_err(|e| anyhow::anyhow!("drawing the frame: {e}"))?;
    let root = backend.into_drawing_area();
    let e = |e: DrawingAreaErrorKind<_>| anyhow::anyhow!("drawing the overlay: {e}");
    draw_image_layers(&root, scene, (w, h)).map_err(e)?;
    if let Some(cal) = scene.calibration
        && let Some(inv) = cal.homography.inverse()
    {
        let to_image = |q: Point| inv.apply(q).filter(|p| in_reach(*p, w, h));
        if let Some(extent) = scene.floor_extent {
            draw_floor_grid(&root, extent, &to_image).map_err(e)?;
        }
        draw_segments(&root, scene.segments, &to_image).map_err(e)?;
        draw_floor_points(&root, cal).map_err(e)?;
    }
    draw_legend(&root, scene).map_err(e)?;
    root.present()
        .map_err(|err| anyhow::anyhow!("writing {}: {err}", out.display()))?;
    Ok(())
}

/// A point as the pixel it falls in.
fn px(p: Point) -> (i32, i32) {
    (p[0].round() as i32, p[1].round() as i32)
}

/// What lies in the image plane: the block grid, the masks (darkened) and the
/// zones (outlined, named).
fn draw_image_layers<DB: DrawingBackend>(
    root: &Area<DB>,
    scene: &Scene,
    (w, h): (u32, u32),
) -> Drawn<DB> {
    let grid = WHITE.mix(0.25);
    let b = scene.block_px.max(1);
    for x in (0..w).step_by(b as usize).skip(1) {
        root.draw(&PathElement::new(
            vec![(x as i32, 0), (x as i32, h as i32)],
            grid,
        ))?;
    }
    for y in (0..h).step_by(b as usize).skip(1) {
        root.draw(&PathElement::new(
            vec![(0, y as i32), (w as i32, y as i32)],
            grid,
        ))?;
    }
    for m in scene.masks {
        let pts: Vec<(i32, i32)> = m.iter().map(|p| px(*p)).collect();
        root.draw(&Polygon::new(pts.clone(), BLACK.mix(0.55).filled()))?;
        root.draw(&PathElement::new(closed(pts), BLACK.stroke_width(2)))?;
    }
    let zone_color = RGBColor(255, 200, 0);
    for z in scene.zones {
        let pts: Vec<(i32, i32)> = z.polygon.iter().map(|p| px(*p)).collect();
        root.draw(&PathElement::new(
            closed(pts.clone()),
            zone_color.stroke_width(2),
        ))?;
        if let Some(&first) = pts.first() {
            label(
                root,
                &format!("zone {}", z.name),
                (first.0 + 4, first.1 + 4),
                &zone_color,
            )?;
        }
    }
    Ok(())
}

/// The floor grid over `[lo, hi]` (metres), 1 m lines, the axes through the
/// origin brighter, labelled at the 5 m crossings; `to_image` maps a floor point
/// into the image (`None` out of reach).
fn draw_floor_grid<DB: DrawingBackend>(
    root: &Area<DB>,
    [lo, hi]: [Point; 2],
    to_image: &dyn Fn(Point) -> Option<Point>,
) -> Drawn<DB> {
    let (w, h) = root.dim_in_pixel();
    let floor = RGBColor(0, 230, 255);
    for (axis, (from, to), (along_lo, along_hi)) in [
        (0, (lo[0], hi[0]), (lo[1], hi[1])),
        (1, (lo[1], hi[1]), (lo[0], hi[0])),
    ] {
        for k in (from.ceil() as i64)..=(to.floor() as i64) {
            let v = k as f64;
            let at = |s: f64| if axis == 0 { [v, s] } else { [s, v] };
            let style = if k == 0 {
                floor.stroke_width(2)
            } else if k % 5 == 0 {
                floor.mix(0.8).stroke_width(1)
            } else {
                floor.mix(0.4).stroke_width(1)
            };
            for run in projected_runs(along_lo, along_hi, &|s| to_image(at(s))) {
                root.draw(&PathElement::new(run, style))?;
            }
        }
    }
    let step = |a: f64| (a / 5.0).ceil() as i64 * 5;
    let mut x = step(lo[0]);
    while (x as f64) <= hi[0] {
        let mut y = step(lo[1]);
        while (y as f64) <= hi[1] {
            if let Some(p) = to_image([x as f64, y as f64]).filter(|p| inside(*p, w, h)) {
                label(
                    root,
                    &format!("({x},{y}) m"),
                    (px(p).0 + 3, px(p).1 - 14),
                    &floor,
                )?;
            }
            y += 5;
        }
        x += 5;
    }
    Ok(())
}

/// The route segments on the floor, outlined and named.
fn draw_segments<DB: DrawingBackend>(
    root: &Area<DB>,
    segments: &[FloorPolygon],
    to_image: &dyn Fn(Point) -> Option<Point>,
) -> Drawn<DB> {
    let (w, h) = root.dim_in_pixel();
    let seg_color = RGBColor(80, 255, 80);
    for s in segments {
        let n = s.polygon_m.len();
        for i in 0..n {
            let (a, b) = (s.polygon_m[i], s.polygon_m[(i + 1) % n]);
            let edge = |t: f64| to_image([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
            for run in projected_runs(0.0, 1.0, &edge) {
                root.draw(&PathElement::new(run, seg_color.stroke_width(3)))?;
            }
        }
        let c = centroid(&s.polygon_m);
        if let Some(p) = to_image(c).filter(|p| inside(*p, w, h)) {
            label(root, &format!("segment {}", s.name), px(p), &seg_color)?;
        }
    }
    Ok(())
}

/// The calibration points: a ring at the image point, a cross where the fit puts
/// the floor point, a line between them, and the residuals.
fn draw_floor_points<DB: DrawingBackend>(root: &Area<DB>, cal: &Calibration) -> Drawn<DB> {
    let (w, h) = root.dim_in_pixel();
    for p in &cal.points {
        let color = if p.flagged {
            RGBColor(255, 40, 40)
        } else {
            RGBColor(255, 0, 255)
        };
        let at = px(p.image_px);
        root.draw(&Circle::new(at, 6, color.stroke_width(2)))?;
        if let Some(m) = p.mapped_image_px.filter(|m| in_reach(*m, w, h)) {
            root.draw(&PathElement::new(vec![at, px(m)], color.stroke_width(2)))?;
            root.draw(&Cross::new(px(m), 4, color.stroke_width(2)))?;
        }
        let text = format!(
            "#{} {:.2} m {:.1} px{}",
            p.index,
            p.residual_m,
            p.residual_px,
            if p.flagged { " OUTLIER" } else { "" }
        );
        label(root, &text, (at.0 + 8, at.1 + 6), &color)?;
    }
    Ok(())
}

/// The legend: the camera and the quality of its floor mapping.
fn draw_legend<DB: DrawingBackend>(root: &Area<DB>, scene: &Scene) -> Drawn<DB> {
    let mut lines = vec![format!("camera {}", scene.camera)];
    match scene.calibration {
        Some(c) => {
            lines.push(format!(
                "{} floor points: RMS {:.3} m / {:.2} px",
                c.points.len(),
                c.rms_m,
                c.rms_px
            ));
            if let (Some(m), Some(p)) = (c.loo_rms_m, c.loo_rms_px) {
                lines.push(format!("leave-one-out RMS {m:.3} m / {p:.2} px"));
            }
            let flagged: Vec<String> = c
                .points
                .iter()
                .filter(|p| p.flagged)
                .map(|p| format!("#{}", p.index))
                .collect();
            if !flagged.is_empty() {
                lines.push(format!("far off: {}", flagged.join(", ")));
            }
            lines.push("floor grid 1 m (cyan), segments (green), zones (yellow)".into());
        }
        None => lines.push("no floor points".into()),
    }
    let height = 18 * lines.len() as i32 + 8;
    root.draw(&Rectangle::new(
        [(0, 0), (430, height)],
        BLACK.mix(0.6).filled(),
    ))?;
    for (i, l) in lines.iter().enumerate() {
        label(root, l, (6, 4 + 18 * i as i32), &WHITE)?;
    }
    Ok(())
}

/// `text` at `at` in `color` on a dark shadow, kept inside the picture.
fn label<DB: DrawingBackend>(
    root: &Area<DB>,
    text: &str,
    at: (i32, i32),
    color: &RGBColor,
) -> Drawn<DB> {
    let style = ("sans-serif", 14).into_font().color(color);
    // A dark shadow keeps text readable on any background.
    let shadow = ("sans-serif", 14).into_font().color(&BLACK);
    // Kept inside the frame: moved left of / above the point near the edges.
    let (w, h) = root.dim_in_pixel();
    let (tw, th) = root.estimate_text_size(text, &style)?;
    let at = (
        if at.0 + tw as i32 > w as i32 {
            (at.0 - tw as i32 - 16).max(0)
        } else {
            at.0
        },
        if at.1 + th as i32 > h as i32 {
            (at.1 - th as i32 - 12).max(0)
        } else {
            at.1
        },
    );
    root.draw(&Text::new(text.to_string(), (at.0 + 1, at.1 + 1), shadow))?;
    root.draw(&Text::new(text.to_string(), at, style))
}

fn closed(mut pts: Vec<(i32, i32)>) -> Vec<(i32, i32)> {
    if let Some(&first) = pts.first() {
        pts.push(first);
    }
    pts
}

fn centroid(pts: &[Point]) -> Point {
    let n = pts.len().max(1) as f64;
    [
        pts.iter().map(|p| p[0]).sum::<f64>() / n,
        pts.iter().map(|p| p[1]).sum::<f64>() / n,
    ]
}

fn inside(p: Point, w: u32, h: u32) -> bool {
    (0.0..w as f64).contains(&p[0]) && (0.0..h as f64).contains(&p[1])
}

/// Near enough to the frame to draw a line to (far beyond it, near the horizon,
/// coordinates explode).
fn in_reach(p: Point, w: u32, h: u32) -> bool {
    let (w, h) = (w as f64, h as f64);
    (-w..2.0 * w).contains(&p[0]) && (-h..2.0 * h).contains(&p[1])
}

/// A floor curve `s ∈ [from, to]` sampled in 200 steps and mapped to the image,
/// split where it leaves the drawable part of the image.
fn projected_runs(from: f64, to: f64, map: &dyn Fn(f64) -> Option<Point>) -> Vec<Vec<(i32, i32)>> {
    const STEPS: usize = 200;
    let mut runs = Vec::new();
    let mut run: Vec<(i32, i32)> = Vec::new();
    for i in 0..=STEPS {
        let s = from + (to - from) * i as f64 / STEPS as f64;
        match map(s) {
            Some(p) => run.push((p[0].round() as i32, p[1].round() as i32)),
            None => {
                if run.len() > 1 {
                    runs.push(std::mem::take(&mut run));
                }
                run.clear();
            }
        }
    }
    if run.len() > 1 {
        runs.push(run);
    }
    runs
}

/// The floor area to draw the grid over: the map grid when configured, else the
/// calibration points' bounding box grown by 5 m.
pub fn floor_extent(
    grid: Option<&isochron_planning::grid::MapGrid>,
    cal: &Calibration,
) -> [Point; 2] {
    let pts: Vec<Point> = match grid {
        Some(g) => vec![
            g.to_map(0.0, 0.0),
            g.to_map(g.width as f64, 0.0),
            g.to_map(g.width as f64, g.height as f64),
            g.to_map(0.0, g.height as f64),
        ],
        None => cal.points.iter().map(|p| p.floor_m).collect(),
    };
    let grow = if grid.is_some() { 0.0 } else { 5.0 };
    let lo = [
        pts.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min) - grow,
        pts.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min) - grow,
    ];
    let hi = [
        pts.iter().map(|p| p[0]).fold(f64::NEG_INFINITY, f64::max) + grow,
        pts.iter().map(|p| p[1]).fold(f64::NEG_INFINITY, f64::max) + grow,
    ];
    [lo, hi]
}
