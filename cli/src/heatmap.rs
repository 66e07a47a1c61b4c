//! `isochron plot heatmap --store PATH --camera ID --out FILE.png`: where and when a
//! camera's view is active, as one picture — a row per block (top to bottom in
//! row-major order, grouped when there are more blocks than rows), a column per
//! minute of the day, the colour the block's long-term mean at that minute
//! (`planning::profile::daily_profile` of the one block; a weekly store is folded
//! onto one day as `plot daily` does). Grey: never learned.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context as _, bail};
use isochron_config::clock::MINUTES_PER_DAY;
use isochron_exit::UsageError;
use isochron_planning::profile::daily_profile;
use isochron_store::Model;
use plotters::prelude::*;

use crate::common::OutFile;
use crate::daily::{Daily, DayFilter};
use crate::store::{StoreArgs, open};

/// Most block rows drawn; more blocks are averaged in groups.
const MAX_ROWS: usize = 480;

#[derive(clap::Args)]
pub(crate) struct HeatmapArgs {
    #[command(flatten)]
    store: StoreArgs,
    /// Output image (`.png`).
    #[arg(long)]
    out: PathBuf,
    /// Title; default names the camera and the days of data.
    #[arg(long)]
    title: Option<String>,
    /// With a model of the week: one weekday (`mon` .. `sun`) or the days of one
    /// type (`workday`, `rest`) instead of the whole week folded onto a day.
    #[arg(long, value_parser = DayFilter::arg)]
    day: Option<DayFilter>,
}

/// Blocks × minutes of the day: `rows` rows of `MINUTES_PER_DAY` values.
pub struct Heat {
    /// Mean per (row, minute), row-major; `None`: never learned.
    pub values: Vec<Option<f64>>,
    /// Rows.
    pub rows: usize,
    /// Blocks per row.
    pub blocks_per_row: usize,
    /// Most days any minute learned from.
    pub days: u32,
}

impl Heat {
    /// The heat map of `model`'s blocks on the days `filter` shows.
    pub fn of(model: &Model, filter: DayFilter) -> Heat {
        let blocks = model.meta.grid.len();
        let per = blocks.div_ceil(MAX_ROWS).max(1);
        let rows = blocks.div_ceil(per);
        let minutes = MINUTES_PER_DAY as usize;
        let mut values = Vec::with_capacity(rows * minutes);
        let mut days = 0;
        for r in 0..rows {
            let group: Vec<u32> = ((r * per) as u32..((r + 1) * per).min(blocks) as u32).collect();
            let points = daily_profile(&[(model, &group)], model.meta.bins() as usize);
            let daily =
                Daily::from_profile(&filter.select(&points, model.meta.cycle, &model.rules));
            days = days.max(daily.days);
            values.extend(daily.mean);
        }
        Heat {
            values,
            rows,
            blocks_per_row: per,
            days,
        }
    }

    /// The value the colour scale tops out at: the 99th percentile of the learned
    /// values (a few hot minutes do not wash out the rest).
    pub fn top(&self) -> f64 {
        let mut v: Vec<f64> = self.values.iter().flatten().copied().collect();
        if v.is_empty() {
            return 1.0;
        }
        v.sort_by(f64::total_cmp);
        let top = v[((v.len() - 1) as f64 * 0.99) as usize];
        if top > 0.0 { top } else { 1.0 }
    }
}

/// A perceptual dark-blue → yellow scale (viridis-like), `x` in 0..=1.
fn colour(x: f64) -> RGBColor {
    const STOPS: [(f64, [f64; 3]); 5] = [
        (0.0, [68.0, 1.0, 84.0]),
        (0.25, [59.0, 82.0, 139.0]),
        (0.5, [33.0, 145.0, 140.0]),
        (0.75, [94.0, 201.0, 98.0]),
        (1.0, [253.0, 231.0, 37.0]),
    ];
    let x = x.clamp(0.0, 1.0);
    let i = STOPS.iter().rposition(|(s, _)| *s <= x).unwrap_or(0).min(3);
    let (s0, c0) = STOPS[i];
    let (s1, c1) = STOPS[i + 1];
    let t = (x - s0) / (s1 - s0);
    let c = |k: usize| (c0[k] + t * (c1[k] - c0[k])).round() as u8;
    RGBColor(c(0), c(1), c(2))
}

pub(crate) fn heatmap(args: HeatmapArgs) -> anyhow::Result<ExitCode> {
    match args
        .out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("png") => {}
        _ => bail!(UsageError(format!(
            "--out {}: expected a .png file name",
            args.out.display()
        ))),
    }
    let store = open(&args.store.store, &args.store.camera)?;
    let model = store.read_model()?;
    let filter = args.day.unwrap_or(DayFilter::All);
    let heat = Heat::of(&model, filter);
    if heat.days == 0 {
        bail!(
            "{} has not learned anything yet: nothing to plot",
            args.store.store.display()
        );
    }
    let title = args.title.clone().unwrap_or_else(|| {
        format!(
            "Activity by block and time of day, camera {} ({} blocks{}), {} {}{}",
            model.meta.camera,
            model.meta.grid.len(),
            if heat.blocks_per_row > 1 {
                format!(", {} per row", heat.blocks_per_row)
            } else {
                String::new()
            },
            heat.days,
            if heat.days == 1 { "day" } else { "days" },
            filter.describe(model.meta.cycle)
        )
    });
    crate::font::load()?;
    // Drawn beside `--out` and renamed into place: a failure leaves no file.
    let file = OutFile::create("--out", &args.out)?;
    draw(file.path(), &heat, &title)?;
    file.commit()?;
    println!(
        "plot: {} written ({} rows × {} minutes, colour scale 0..{:.4})",
        args.out.display(),
        heat.rows,
        MINUTES_PER_DAY,
        heat.top()
    );
    Ok(ExitCode::SUCCESS)
}

fn draw(out: &std::path::Path, heat: &Heat, title: &str) -> anyhow::Result<()> {
    let minutes = MINUTES_PER_DAY as usize;
    // One pixel per 2 minutes, one or more per row.
    let cols = minutes / 2;
    let row_px = (480 / heat.rows).max(1);
    let (left, right, top_m, bottom) = (80u32, 110u32, 50u32, 50u32);
    let (w, h) = (
        left + cols as u32 + right,
        top_m + (heat.rows * row_px) as u32 + bottom,
    );
    let root = BitMapBackend::new(out, (w, h)).into_drawing_area();
    let e = |e: DrawingAreaErrorKind<_>| anyhow::anyhow!("drawing the heat map: {e}");
    root.fill(&WHITE).map_err(e)?;
    let font = ("sans-serif", 16).into_font();
    root.draw(&Text::new(title.to_string(), (10, 12), font.clone()))
        .map_err(e)?;
    let top = heat.top();
    let pixels = heat_pixels(heat, cols, row_px);
    let area = root.margin(top_m as i32, bottom as i32, left as i32, right as i32);
    area.draw(
        &BitMapElement::with_owned_buffer(
            (0, 0),
            (cols as u32, (heat.rows * row_px) as u32),
            pixels,
        )
        .context("the heat map's pixels")?,
    )
    .map_err(e)?;
    // Hour ticks.
    let small = ("sans-serif", 13).into_font();
    let y0 = (top_m + (heat.rows * row_px) as u32) as i32;
    for hour in (0..=24).step_by(3) {
        let x = left as i32 + hour * 30;
        root.draw(&PathElement::new(vec![(x, y0), (x, y0 + 5)], BLACK))
            .map_err(e)?;
        root.draw(&Text::new(
            format!("{hour:02}:00"),
            (x - 18, y0 + 8),
            small.clone(),
        ))
        .map_err(e)?;
    }
    root.draw(&Text::new(
        "time of day".to_string(),
        (left as i32 + cols as i32 / 2 - 35, y0 + 28),
        small.clone(),
    ))
    .map_err(e)?;
    root.draw(&Text::new(
        "block (top left →".to_string(),
        (4, top_m as i32),
        small.clone(),
    ))
    .map_err(e)?;
    root.draw(&Text::new(
        "bottom right)".to_string(),
        (4, top_m as i32 + 16),
        small.clone(),
    ))
    .map_err(e)?;
    let scale_x = (left + cols as u32 + 20) as i32;
    let scale_h = (heat.rows * row_px) as i32;
    draw_scale(&root, (scale_x, top_m as i32), scale_h, top).map_err(e)?;
    root.present()
        .map_err(|err| anyhow::anyhow!("writing {}: {err}", out.display()))?;
    Ok(())
}

/// The heat map's pixels (RGB, `cols` × `heat.rows · row_px`): each column the
/// mean of two minutes, grey where nothing was learned.
fn heat_pixels(heat: &Heat, cols: usize, row_px: usize) -> Vec<u8> {
    let minutes = MINUTES_PER_DAY as usize;
    let top = heat.top();
    let grey = RGBColor(200, 200, 200);
    let mut pixels = vec![0u8; cols * heat.rows * row_px * 3];
    for r in 0..heat.rows {
        for c in 0..cols {
            let pair = [
                heat.values[r * minutes + 2 * c],
                heat.values[r * minutes + 2 * c + 1],
            ];
            let learned: Vec<f64> = pair.iter().flatten().copied().collect();
            let RGBColor(red, green, blue) = if learned.is_empty() {
                grey
            } else {
                colour(learned.iter().sum::<f64>() / learned.len() as f64 / top)
            };
            for dy in 0..row_px {
                let i = ((r * row_px + dy) * cols + c) * 3;
                pixels[i..i + 3].copy_from_slice(&[red, green, blue]);
            }
        }
    }
    pixels
}

/// The colour scale at `(sx, top_m)`, `sh` pixels high, from 0 to `top`.
fn draw_scale<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    (sx, top_m): (i32, i32),
    sh: i32,
    top: f64,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let small = ("sans-serif", 13).into_font();
    for y in 0..sh {
        let v = 1.0 - y as f64 / sh.max(1) as f64;
        root.draw(&PathElement::new(
            vec![(sx, top_m + y), (sx + 16, top_m + y)],
            colour(v),
        ))?;
    }
    for (v, y) in [(top, 0), (top / 2.0, sh / 2), (0.0, sh)] {
        root.draw(&Text::new(
            format!("{v:.3}"),
            (sx + 20, top_m + y - 6),
            small.clone(),
        ))?;
    }
    root.draw(&Text::new("mean".to_string(), (sx, top_m - 18), small))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colours_run_dark_to_bright() {
        let lum = |c: RGBColor| c.0 as u32 + c.1 as u32 + c.2 as u32;
        let steps: Vec<u32> = (0..=10).map(|i| lum(colour(i as f64 / 10.0))).collect();
        assert!(steps.windows(2).all(|w| w[0] <= w[1] + 5), "{steps:?}");
        assert_eq!(colour(2.0), colour(1.0));
    }
}
