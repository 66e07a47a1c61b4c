//! Path planning on segments and routes, as in the paper (sections "Off-line" and
//! "Real-time Global Path Planning").
//!
//! A path segment `p` is a floor polygon (its blocks: those of every camera whose
//! centre lands inside it) or a camera's zone (its blocks: those whose centre is in
//! the zone). Its activity is the mean over its blocks:
//!
//! * `M_p(t*)`: the long-term mean at isochronal time t* (from the long-term store);
//! * `M'_p`: 1 if `M_p(t*)` exceeds `min_activity` at any t*, else 0 — people never
//!   go there, so neither should the robot;
//! * `M_p(now)`: the short-term activity now, `weight_in_place·S1 + weight_moving·S2`.
//!
//! and, with `Cost(M) = min(cap, 100·M / cost_scale)`:
//!
//! * `cost1(route, t*) = Σ Cost(M_p(t*))` over the route's segments, infinite if any
//!   `M'_p = 0`;
//! * `cost2(route, now) = w1·cost1(route, t* = now) + w2·Σ Cost(M_p(now))`.
//!
//! Where the long-term model has no data at t* (a camera never ran then), `cost1`
//! is unknown (NaN) and is left out of curves; a segment without live activity
//! uses its long-term `M_p(t*)` as the estimate of `M_p(now)` (flagged).

use std::collections::BTreeMap;

use isochron_config::clock::MINUTES_PER_DAY;
use isochron_config::{CameraConfig, RouteConfig, SegmentConfig};
use isochron_store::Model;
use isochron_wire::geometry::{BlockGrid, point_in_polygon};

use crate::cost::CostParams;
use crate::homography::Homography;
use crate::profile::{ProfilePoint, daily_profile};

/// Why a plan cannot be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    /// No such route in the config.
    #[error("no route '{0}' in [[costmap.route]] (configured: {1})")]
    UnknownRoute(String, String),
    /// No such segment in the config.
    #[error("no segment '{0}' in [[costmap.segment]] (configured: {1})")]
    UnknownSegment(String, String),
    /// The segment covers no block of any camera.
    #[error(
        "segment '{0}' covers no block of any camera: check its polygon_m against the cameras' floor_points, or its zone"
    )]
    EmptySegment(String),
    /// Data is missing (a store, a camera's block grid).
    #[error("{0}")]
    NoData(String),
    /// The stores of a weekly model learned nothing on the day asked for.
    #[error(
        "nothing learned for {day}: the long-term stores learned {learned} (a weekly model draws and plans a day only once that weekday was seen)"
    )]
    DayNotLearned {
        /// The day asked for (`sun`).
        day: String,
        /// The days learned (`mon, tue, wed`).
        learned: String,
    },
    /// The configuration cannot be used (a camera's floor points).
    #[error("{0}")]
    Config(String),
}

/// What the planner knows of a camera: its id, config, homography and block grid.
#[derive(Debug, Clone)]
pub struct CameraGeometry {
    /// The camera's config.
    pub config: CameraConfig,
    /// Image → floor, if the camera has floor points.
    pub homography: Option<Homography>,
    /// Its block grid, if known (from the store or the activity stream).
    pub blocks: Option<BlockGrid>,
}

/// The blocks of a segment, per camera (index into the camera list).
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentBlocks {
    /// Segment name.
    pub name: String,
    /// `(camera index, block indices)`, cameras with at least one block.
    pub blocks: Vec<(usize, Vec<u32>)>,
}

impl SegmentBlocks {
    /// Number of blocks over all cameras.
    pub fn len(&self) -> usize {
        self.blocks.iter().map(|(_, b)| b.len()).sum()
    }

    /// True if no block.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The segment's blocks paired with their camera's model (`models[k]` for camera
    /// `k`), as [`daily_profile`] takes them; cameras without a model are left out.
    pub fn model_blocks<'a>(&'a self, models: &[Option<&'a Model>]) -> Vec<(&'a Model, &'a [u32])> {
        self.blocks
            .iter()
            .filter_map(|(k, blocks)| Some((models.get(*k).copied().flatten()?, blocks.as_slice())))
            .collect()
    }
}

/// Finds the blocks of `segment` among `cameras`; an error if it has none.
pub fn resolve_segment(
    segment: &SegmentConfig,
    cameras: &[CameraGeometry],
) -> Result<SegmentBlocks, PlanError> {
    let mut blocks = Vec::new();
    if let Some(poly) = &segment.polygon_m {
        for (k, cam) in cameras.iter().enumerate() {
            let (Some(h), Some(grid)) = (&cam.homography, &cam.blocks) else {
                continue;
            };
            let inside: Vec<u32> = (0..grid.len())
                .filter(|&b| {
                    h.apply(grid.center(b))
                        .is_some_and(|p| point_in_polygon(p, poly))
                })
                .map(|b| b as u32)
                .collect();
            if !inside.is_empty() {
                blocks.push((k, inside));
            }
        }
    } else if let (Some(camera), Some(zone)) = (&segment.camera, &segment.zone)
        && let Some((k, cam)) = cameras
            .iter()
            .enumerate()
            .find(|(_, c)| &c.config.id == camera)
    {
        let Some(grid) = cam.blocks else {
            return Err(PlanError::NoData(format!(
                "segment '{}': the block grid of camera '{camera}' is not known yet (no long-term store, no activity)",
                segment.name
            )));
        };
        let zones = cam
            .config
            .zones_or_default(grid.frame_width, grid.frame_height);
        if let Some(z) = zones.iter().find(|z| &z.name == zone) {
            let inside = grid.blocks_in(&z.polygon);
            if !inside.is_empty() {
                blocks.push((k, inside));
            }
        }
    }
    let resolved = SegmentBlocks {
        name: segment.name.clone(),
        blocks,
    };
    if resolved.is_empty() {
        return Err(PlanError::EmptySegment(segment.name.clone()));
    }
    Ok(resolved)
}

/// A segment's long-term activity over the cycle.
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentProfile {
    /// Segment name.
    pub name: String,
    /// `M_p(t*)` per bin of the cycle; `None` where no camera of the segment has
    /// learned that bin.
    pub m_p: Vec<Option<f64>>,
    /// `M'_p`: true if the segment ever saw activity above `min_activity`.
    pub m_prime: bool,
}

impl SegmentProfile {
    /// The long-term profile of `segment` from the cameras' models (`models[k]` for
    /// camera `k`; a camera without a model contributes nothing). `bins` is the
    /// cycle's length.
    pub fn from_models(
        segment: &SegmentBlocks,
        models: &[Option<&Model>],
        bins: usize,
        min_activity: f64,
    ) -> SegmentProfile {
        let points = daily_profile(&segment.model_blocks(models), bins);
        SegmentProfile::from_points(&segment.name, &points, min_activity)
    }

    /// The profile of segment `name` from its [`daily_profile`].
    pub fn from_points(name: &str, points: &[ProfilePoint], min_activity: f64) -> SegmentProfile {
        let m_p: Vec<Option<f64>> = points.iter().map(|p| p.mean).collect();
        let m_prime = m_p.iter().flatten().any(|&m| m > min_activity);
        SegmentProfile {
            name: name.to_string(),
            m_p,
            m_prime,
        }
    }

    /// `M_p(t*)`.
    pub fn at(&self, t_star: u32) -> Option<f64> {
        self.m_p.get(t_star as usize).copied().flatten()
    }
}

/// `cost1(route, t*)`: Σ Cost(M_p(t*)); infinite if a segment has `M'_p = 0`; NaN if
/// some segment has no long-term data at t*.
pub fn cost1(route: &[&SegmentProfile], t_star: u32, params: &CostParams) -> f64 {
    if route.iter().any(|p| !p.m_prime) {
        return f64::INFINITY;
    }
    let mut sum = 0.0;
    for p in route {
        match p.at(t_star) {
            Some(m) => sum += params.cost_of(m),
            None => return f64::NAN,
        }
    }
    sum
}

/// The profiles of a route's segments, in order.
pub fn route_profiles<'a>(
    route: &RouteConfig,
    profiles: &'a BTreeMap<String, SegmentProfile>,
) -> Result<Vec<&'a SegmentProfile>, PlanError> {
    route
        .segments
        .iter()
        .map(|s| {
            profiles.get(s).ok_or_else(|| {
                PlanError::UnknownSegment(
                    s.clone(),
                    profiles.keys().cloned().collect::<Vec<_>>().join(", "),
                )
            })
        })
        .collect()
}

/// The minutes an off-line plan looks at.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DayRange {
    /// First minute of the day, 0..1440.
    pub start: u32,
    /// End minute, exclusive, 1..=1440; at or below `start` the range wraps past
    /// midnight.
    pub end: u32,
    /// Minutes per curve point.
    pub step: u32,
    /// Added to each minute of the day to get t* (weekly cycle: day × 1440).
    pub cycle_offset: u32,
}

impl DayRange {
    /// The whole day in steps of `step` minutes.
    pub fn whole_day(step: u32) -> DayRange {
        DayRange {
            start: 0,
            end: MINUTES_PER_DAY,
            step: step.max(1),
            cycle_offset: 0,
        }
    }

    /// Length in minutes.
    pub fn minutes(&self) -> u32 {
        if self.end > self.start {
            self.end - self.start
        } else {
            MINUTES_PER_DAY - self.start + self.end
        }
    }
}

/// One point of an off-line cost curve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CurvePoint {
    /// Minute of the day the point starts at.
    pub minute: u32,
    /// Mean `cost1` over the point's minutes (infinite, or NaN if no data).
    pub cost: f64,
}

/// A run of curve points near the cheapest cost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    /// First minute of the day.
    pub start: u32,
    /// End minute, exclusive (can pass 1440 when the range wraps past midnight).
    pub end: u32,
    /// Mean cost over the window.
    pub cost: f64,
}

/// An off-line plan: the cost curve of a route and its cheapest departure times.
#[derive(Debug, Clone, PartialEq)]
pub struct OfflinePlan {
    /// The route.
    pub route: String,
    /// The range and step.
    pub range: DayRange,
    /// The curve, one point per step.
    pub curve: Vec<CurvePoint>,
    /// Segments with `M'_p = 0` (the route is infinitely expensive if any).
    pub never_active: Vec<String>,
    /// The cheapest windows: runs of points within [`WINDOW_MARGIN`] of the
    /// cheapest, cheapest first.
    pub windows: Vec<Window>,
    /// The cheapest points, cheapest first (ties: earlier first), at most 5.
    pub best: Vec<CurvePoint>,
}

/// A window holds the points whose cost is within this fraction of the curve's
/// range (max − min) above its minimum.
pub const WINDOW_MARGIN: f64 = 0.05;

/// Plans `route` off-line over `range`.
pub fn plan_offline(
    route: &RouteConfig,
    profiles: &[&SegmentProfile],
    range: DayRange,
    params: &CostParams,
) -> OfflinePlan {
    let never_active: Vec<String> = profiles
        .iter()
        .filter(|p| !p.m_prime)
        .map(|p| p.name.clone())
        .collect();
    let total = range.minutes();
    let step = range.step.max(1);
    let mut curve = Vec::new();
    let mut offset = 0;
    while offset < total {
        let minute = (range.start + offset) % MINUTES_PER_DAY;
        let n = step.min(total - offset);
        let (mut sum, mut count, mut infinite) = (0.0, 0u32, false);
        for k in 0..n {
            let m = (minute + k) % MINUTES_PER_DAY;
            let c = cost1(profiles, range.cycle_offset + m, params);
            if c.is_infinite() {
                infinite = true;
            } else if c.is_finite() {
                sum += c;
                count += 1;
            }
        }
        let cost = if infinite {
            f64::INFINITY
        } else if count == 0 {
            f64::NAN
        } else {
            sum / count as f64
        };
        curve.push(CurvePoint { minute, cost });
        offset += step;
    }
    let (windows, best) = cheapest_windows(&curve, total, step);
    OfflinePlan {
        route: route.name.clone(),
        range,
        curve,
        never_active,
        windows,
        best,
    }
}

/// The runs of `curve` points within [`WINDOW_MARGIN`] of its cheapest finite
/// cost, cheapest first (ties: earlier first), and its cheapest points (at most
/// 5, ties earlier first); point `k` of the curve starts `k · step` minutes into a
/// range of `total` minutes.
pub fn cheapest_windows(
    curve: &[CurvePoint],
    total: u32,
    step: u32,
) -> (Vec<Window>, Vec<CurvePoint>) {
    let finite: Vec<&CurvePoint> = curve.iter().filter(|p| p.cost.is_finite()).collect();
    let mut windows = Vec::new();
    let mut best = Vec::new();
    if !finite.is_empty() {
        let min = finite.iter().map(|p| p.cost).fold(f64::INFINITY, f64::min);
        let max = finite
            .iter()
            .map(|p| p.cost)
            .fold(f64::NEG_INFINITY, f64::max);
        let limit = min + (WINDOW_MARGIN * (max - min)).max(1e-9);
        let mut run: Option<(usize, usize)> = None;
        let close = |(a, b): (usize, usize), windows: &mut Vec<Window>| {
            let pts = &curve[a..=b];
            let cost = pts.iter().map(|p| p.cost).sum::<f64>() / pts.len() as f64;
            let start = curve[a].minute;
            let length: u32 = ((b - a) as u32) * step + step.min(total - (b as u32) * step);
            windows.push(Window {
                start,
                end: start + length,
                cost,
            });
        };
        for (k, p) in curve.iter().enumerate() {
            let near = p.cost.is_finite() && p.cost <= limit;
            run = match (run, near) {
                (None, true) => Some((k, k)),
                (Some((a, _)), true) => Some((a, k)),
                (Some(r), false) => {
                    close(r, &mut windows);
                    None
                }
                (None, false) => None,
            };
        }
        if let Some(r) = run {
            close(r, &mut windows);
        }
        windows.sort_by(|a, b| a.cost.total_cmp(&b.cost).then(a.start.cmp(&b.start)));
        let mut sorted: Vec<CurvePoint> = finite.into_iter().copied().collect();
        sorted.sort_by(|a, b| a.cost.total_cmp(&b.cost));
        best = sorted.into_iter().take(5).collect();
    }
    (windows, best)
}

/// A route's real-time cost.
#[derive(Debug, Clone, PartialEq)]
pub struct RouteNow {
    /// Route name.
    pub name: String,
    /// `cost1(route, t* = now)` (unknown long-term data counts as 0, flagged).
    pub cost1: f64,
    /// `Σ Cost(M_p(now))`.
    pub short_term: f64,
    /// `w1·cost1 + w2·short_term`; infinite if a segment never saw activity.
    pub cost2: f64,
    /// A segment never saw activity (`M'_p = 0`).
    pub infinite: bool,
    /// Some segment had no live activity; its long-term mean stood in.
    pub estimated: bool,
    /// Some segment had no long-term data at t*.
    pub no_long_term: bool,
}

/// One segment's terms of Cost2 at one t*: what [`plan_now`] adds up over a
/// route, and what a route graph's edge costs on its own
/// ([`crate::route_graph::EdgeScorer`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SegmentCosts {
    /// `Cost(M_p(t*))` (0 without long-term data).
    pub long_term: f64,
    /// `Cost(M_p(now))`; without live activity, the long-term mean's cost.
    pub short_term: f64,
    /// No live activity: the long-term mean stood in for it.
    pub estimated: bool,
    /// No long-term data at t*.
    pub no_long_term: bool,
}

impl SegmentCosts {
    /// The terms of a segment whose long-term mean activity at t* is `long` and
    /// whose activity now is `now` (`None`: unknown).
    pub fn of(long: Option<f64>, now: Option<f64>, params: &CostParams) -> SegmentCosts {
        let long_term = long.map_or(0.0, |m| params.cost_of(m));
        SegmentCosts {
            long_term,
            short_term: now.map_or(long_term, |m| params.cost_of(m)),
            estimated: now.is_none(),
            no_long_term: long.is_none(),
        }
    }

    /// `w1 · Cost(M_p(t*)) + w2 · Cost(M_p(now))`.
    pub fn cost2(&self, w1: f64, w2: f64) -> f64 {
        cost2(self.long_term, self.short_term, w1, w2)
    }
}

/// The paper's (11): `Cost2 = w1 · Cost1 + w2 · Σ Cost(M_p(now))`.
pub fn cost2(cost1: f64, short_term: f64, w1: f64, w2: f64) -> f64 {
    w1 * cost1 + w2 * short_term
}

/// Ranks `routes` by `cost2` at isochronal time `t_star`, cheapest first (infinite
/// last, ties by name). `now[segment]` is `M_p(now)`, `None` without live data.
pub fn plan_now(
    routes: &[(&RouteConfig, Vec<&SegmentProfile>)],
    now: &BTreeMap<String, Option<f64>>,
    t_star: u32,
    params: &CostParams,
    w1: f64,
    w2: f64,
) -> Vec<RouteNow> {
    let mut out: Vec<RouteNow> = routes
        .iter()
        .map(|(route, profiles)| {
            let infinite = profiles.iter().any(|p| !p.m_prime);
            let (mut c1, mut short) = (0.0, 0.0);
            let (mut estimated, mut no_long_term) = (false, false);
            for p in profiles {
                let costs =
                    SegmentCosts::of(p.at(t_star), now.get(&p.name).copied().flatten(), params);
                c1 += costs.long_term;
                short += costs.short_term;
                estimated |= costs.estimated;
                no_long_term |= costs.no_long_term;
            }
            let cost1 = if infinite { f64::INFINITY } else { c1 };
            let cost2 = if infinite {
                f64::INFINITY
            } else {
                cost2(c1, short, w1, w2)
            };
            RouteNow {
                name: route.name.clone(),
                cost1,
                short_term: short,
                cost2,
                infinite,
                estimated,
                no_long_term,
            }
        })
        .collect();
    out.sort_by(|a, b| a.cost2.total_cmp(&b.cost2).then(a.name.cmp(&b.name)));
    out
}

/// `M_p(now)` of a segment: the mean short-term activity over its blocks of the
/// cameras with live data (`live[k]`: camera `k`'s latest activity per block).
pub fn segment_now(
    segment: &SegmentBlocks,
    live: &[Option<&[isochron_wire::BlockActivity]>],
    params: &CostParams,
) -> Option<f64> {
    let (mut sum, mut n) = (0.0, 0usize);
    for (k, blocks) in &segment.blocks {
        let Some(Some(acts)) = live.get(*k) else {
            continue;
        };
        for &b in blocks {
            if let Some(a) = acts.get(b as usize) {
                sum += params.short_term_activity(a);
                n += 1;
            }
        }
    }
    (n > 0).then(|| sum / n as f64)
}

/// The block grid a camera's store was made for.
pub fn store_block_grid(model: &Model) -> BlockGrid {
    model.meta.grid
}

#[cfg(test)]
mod tests;
