//! `isochron plot daily --store PATH --camera ID --out FILE.png|.svg [--block X,Y]`:
//! the isochronal activity of a camera over the day, in the style of the paper's
//! figure of hallway activity — activity against the time of day, with red vertical
//! lines at the quiet times of the working day, when a robot best plans to pass.
//!
//! The curve is the long-term mean of the selected blocks per minute (as
//! `isochron store export` writes it), drawn over a band of ± one sigma, with its
//! 15-minute running mean on top. A weekly store is folded onto one day (each minute
//! averaged over the days of the week, weighted by how many weeks taught it). The
//! selection of blocks is a [`Selection`], so a later `--segment NAME` (a floor
//! polygon of the site) adds a variant there, not a new plot.
//!
//! Text is drawn with the font inside the binary ([`crate::font`]).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::bail;
use isochron_config::clock::format_t_star;
use isochron_exit::UsageError;
use isochron_planning::planner::Planner;
use isochron_store::Model;
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use crate::common::{OutFile, Subcommands, load_config};
use crate::daily::{Daily, DayFilter, running_mean, runs};
use crate::store::{Selection, StoreArgs, open, profile};

/// Plot a camera's long-term activity.
pub type Args = Subcommands<Command>;

#[derive(clap::Subcommand)]
pub(crate) enum Command {
    /// Activity over the day (PNG or SVG, by the file's extension).
    Daily(DailyArgs),
    /// Blocks × minute of the day: where and when the view is active (PNG).
    Heatmap(crate::heatmap::HeatmapArgs),
}

#[derive(clap::Args)]
pub(crate) struct DailyArgs {
    #[command(flatten)]
    store: Option<StoreArgs>,
    /// Instead of `--store`/`--camera`: a path segment of the site (a
    /// [[costmap.segment]] name), its long-term activity M_p(t*) over the day.
    #[arg(long, conflicts_with_all = ["store", "camera", "block"])]
    segment: Option<String>,
    /// With `--segment`: the site configuration (default: $ISOCHRON_CONFIG or
    /// /etc/isochron/isochron.toml).
    #[arg(long, requires = "segment")]
    config: Option<PathBuf>,
    /// Output image: `.png` or `.svg`.
    #[arg(long)]
    out: PathBuf,
    /// One block, `X,Y`, instead of all blocks.
    #[arg(long, value_name = "X,Y", value_parser = Selection::arg)]
    block: Option<Selection>,
    /// With a model of the week: one weekday (`mon` .. `sun`) or the days of one
    /// type (`workday`, `rest`) instead of the whole week folded onto a day.
    #[arg(long, value_parser = DayFilter::arg)]
    day: Option<DayFilter>,
    /// Title; default names the camera, the blocks and the days of data.
    #[arg(long)]
    title: Option<String>,
    /// Image width, pixels.
    #[arg(long, default_value_t = 1200)]
    width: u32,
    /// Image height, pixels.
    #[arg(long, default_value_t = 520)]
    height: u32,
    /// Start of the working day (quiet times are looked for between start and end).
    #[arg(long, default_value = "06:00", value_name = "HH:MM", value_parser = crate::values::time_of_day)]
    day_start: u32,
    /// End of the working day.
    #[arg(long, default_value = "21:00", value_name = "HH:MM", value_parser = crate::values::time_of_day)]
    day_end: u32,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    match args.command {
        Command::Daily(a) => daily(a),
        Command::Heatmap(a) => crate::heatmap::heatmap(a),
    }
}

/// The image format, from the file name.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Format {
    Png,
    Svg,
}

fn format_of(path: &Path) -> anyhow::Result<Format> {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("png") => Ok(Format::Png),
        Some("svg") => Ok(Format::Svg),
        _ => bail!(UsageError(format!(
            "--out {}: expected a .png or .svg file name",
            path.display()
        ))),
    }
}

fn daily(args: DailyArgs) -> anyhow::Result<ExitCode> {
    let format = format_of(&args.out)?;
    let (day_start, day_end) = (args.day_start, args.day_end);
    let filter = args.day.unwrap_or(DayFilter::All);
    if let Some(segment) = &args.segment {
        let (daily, title) = segment_daily(args.config.clone(), segment, filter)?;
        let title = args.title.clone().unwrap_or(title);
        return render(&args, format, day_start, day_end, &daily, &title);
    }
    let Some(store_args) = &args.store else {
        bail!(UsageError(
            "give --store PATH --camera ID (a camera's activity), or --segment NAME (a path segment's)"
                .into()
        ));
    };
    let store = open(&store_args.store, &store_args.camera)?;
    let model: Model = store.read_model()?;
    let selection = args.block.clone().unwrap_or(Selection::All);
    let cycle = model.meta.cycle;
    let points = filter.select(&profile(&model, &selection)?, cycle, &model.rules);
    let daily = Daily::from_profile(&points);
    if daily.days == 0 {
        bail!(
            "{} has not learned anything yet: nothing to plot",
            store_args.store.display()
        );
    }
    let what = selection.describe(model.meta.grid.grid_w(), model.meta.grid.grid_h());
    let title = args.title.clone().unwrap_or_else(|| {
        format!(
            "Isochronal activity, camera {} ({what}), {} {}{}",
            model.meta.camera,
            daily.days,
            if daily.days == 1 { "day" } else { "days" },
            filter.describe(cycle)
        )
    });
    render(&args, format, day_start, day_end, &daily, &title)
}

/// The long-term activity of a path segment over the day, for
/// `isochron plot daily --segment NAME`, and the plot's default title. A weekly
/// cycle is folded onto one day (weighted by the days that taught each minute).
fn segment_daily(
    config: Option<PathBuf>,
    segment: &str,
    filter: DayFilter,
) -> anyhow::Result<(Daily, String)> {
    let loaded = load_config(config)?;
    let mut planner = Planner::new(&loaded)?;
    let seg = planner.segment_daily(segment)?;
    let rules = isochron_store::Rules::of(&loaded.config.cascade);
    let daily = Daily::from_profile(&filter.select(&seg.points, planner.cycle(), &rules));
    if daily.days == 0 {
        bail!("segment '{segment}' has no long-term data yet: nothing to plot");
    }
    let c = &loaded.config.costmap;
    let title = format!(
        "Isochronal activity M_p(t*), segment {segment}, {} {}{} (Cost = 100·M/{}, cap {}){}",
        daily.days,
        if daily.days == 1 { "day" } else { "days" },
        filter.describe(planner.cycle()),
        c.cost_scale,
        c.cap,
        if seg.profile.m_prime {
            ""
        } else {
            " — never active: M'_p = 0"
        }
    );
    Ok((daily, title))
}

/// Draws `daily` into `args.out` and reports the quiet times.
fn render(
    args: &DailyArgs,
    format: Format,
    day_start: u32,
    day_end: u32,
    daily: &Daily,
    title: &str,
) -> anyhow::Result<ExitCode> {
    let quiet = daily.quiet_times(day_start, day_end, 3);
    crate::font::load()?;
    let size = (args.width.clamp(300, 8000), args.height.clamp(200, 8000));
    // Drawn beside `--out` and renamed into place: a failure leaves no file.
    let file = OutFile::create("--out", &args.out)?;
    match format {
        Format::Png => {
            let root = BitMapBackend::new(file.path(), size).into_drawing_area();
            draw(&root, daily, &quiet, title)?;
            root.present()
                .map_err(|e| anyhow::anyhow!("writing {}: {e}", args.out.display()))?;
        }
        Format::Svg => {
            let root = SVGBackend::new(file.path(), size).into_drawing_area();
            draw(&root, daily, &quiet, title)?;
            root.present()
                .map_err(|e| anyhow::anyhow!("writing {}: {e}", args.out.display()))?;
        }
    }
    file.commit()?;
    let times: Vec<String> = quiet.iter().map(|&m| format_t_star(m)).collect();
    println!(
        "plot: {} written; quiet times of the working day: {}",
        args.out.display(),
        if times.is_empty() {
            "none found".to_string()
        } else {
            times.join(", ")
        }
    );
    Ok(ExitCode::SUCCESS)
}

/// Draws the plot on any plotters backend.
fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    daily: &Daily,
    quiet: &[u32],
    title: &str,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow::anyhow!("drawing the plot: {e}");
    root.fill(&WHITE).map_err(e)?;
    let top = daily
        .mean
        .iter()
        .zip(&daily.sigma)
        .filter_map(|(m, s)| Some(m.as_ref()? + s.as_ref()?))
        .fold(0.0, f64::max);
    let y_max = if top > 0.0 { top * 1.1 } else { 1.0 };
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 22).into_font())
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size(72)
        .build_cartesian_2d(0f64..24f64, 0f64..y_max)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_labels(13)
        .x_label_formatter(&|h| format!("{:02}:00", *h as u32))
        .x_desc("time of day")
        .y_desc("activity (mean M_L1 per block)")
        .y_label_formatter(&|v| format!("{v:.3}"))
        .light_line_style(WHITE.mix(0.0))
        .label_style(("sans-serif", 15))
        .draw()
        .map_err(e)?;

    let hour = |m: usize| m as f64 / 60.0;
    let band = RGBColor(70, 110, 200).mix(0.18);
    let raw = RGBColor(70, 110, 200).mix(0.55);
    let smooth_color = RGBColor(20, 40, 130);
    let smooth = daily.smoothed(15);
    // The band is drawn from the 15-minute running sigma: per-minute sigmas of single
    // blocks are too ragged to read.
    let sigma = running_mean(&daily.sigma, 15);
    for (i, run) in runs(&daily.mean).into_iter().enumerate() {
        let first = i == 0;
        let at = |m: usize| (smooth[m].unwrap_or(0.0), sigma[m].unwrap_or(0.0));
        let mut poly: Vec<(f64, f64)> = run.clone().map(|m| (hour(m), at(m).0 + at(m).1)).collect();
        poly.extend(
            run.clone()
                .rev()
                .map(|m| (hour(m), (at(m).0 - at(m).1).max(0.0))),
        );
        let series = chart
            .draw_series(std::iter::once(Polygon::new(poly, band.filled())))
            .map_err(e)?;
        if first {
            series
                .label("± sigma (typical block)")
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 20, y + 5)], band.filled()));
        }
        let series = chart
            .draw_series(LineSeries::new(
                run.clone().map(|m| (hour(m), daily.mean[m].unwrap_or(0.0))),
                raw.stroke_width(1),
            ))
            .map_err(e)?;
        if first {
            series.label("mean per minute").legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], raw.stroke_width(1))
            });
        }
        let series = chart
            .draw_series(LineSeries::new(
                run.map(|m| (hour(m), smooth[m].unwrap_or(0.0))),
                smooth_color.stroke_width(3),
            ))
            .map_err(e)?;
        if first {
            series.label("15-minute mean").legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], smooth_color.stroke_width(3))
            });
        }
    }
    draw_quiet(&mut chart, quiet, y_max).map_err(e)?;
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(e)?;
    Ok(())
}

/// The quiet times: a red line each, labelled with its time.
fn draw_quiet<DB: DrawingBackend>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    quiet: &[u32],
    y_max: f64,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    for (i, &m) in quiet.iter().enumerate() {
        let x = m as f64 / 60.0;
        let series = chart.draw_series(std::iter::once(PathElement::new(
            vec![(x, 0.0), (x, y_max)],
            RED.stroke_width(2),
        )))?;
        if i == 0 {
            series
                .label("quiet time to plan a robot's pass")
                .legend(|(x, y)| {
                    PathElement::new(vec![(x + 10, y - 6), (x + 10, y + 6)], RED.stroke_width(2))
                });
        }
        chart.draw_series(std::iter::once(Text::new(
            format_t_star(m),
            (x + 0.1, y_max * 0.97),
            ("sans-serif", 15).into_font().color(&RED),
        )))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_png_and_svg() {
        let dir = tempfile::tempdir().unwrap();
        crate::font::load().unwrap();
        let daily = crate::daily::tests::office();
        let quiet = daily.quiet_times(360, 1260, 3);
        let png = dir.path().join("a.png");
        {
            let root = BitMapBackend::new(&png, (800, 400)).into_drawing_area();
            draw(&root, &daily, &quiet, "office").unwrap();
            root.present().unwrap();
        }
        let bytes = std::fs::read(&png).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
        let svg = dir.path().join("a.svg");
        {
            let root = SVGBackend::new(&svg, (800, 400)).into_drawing_area();
            draw(&root, &daily, &quiet, "office").unwrap();
            root.present().unwrap();
        }
        let text = std::fs::read_to_string(&svg).unwrap();
        assert!(text.contains("<svg") && text.contains("office"));
        assert!(text.contains("12:"), "the lull is labelled");
        assert!(format_of(Path::new("x.jpg")).is_err());
        assert_eq!(format_of(Path::new("x.SVG")).unwrap(), Format::Svg);
    }
}
