//! Each edge's corridor on the map grid, found once, and the edges' costs and
//! blocked state from a cost map, a sum per edge.
//!
//! An edge's corridor is the cells whose centre lies within half its width of its
//! line. The corridor is cut into cross-sections one cell long along the line
//! (each cell belongs to the section its nearest point on the line falls in); the
//! round caps beyond the end nodes, and sections the grid's border cuts, belong to
//! none. An edge is *blocked* when, in some cross-section, every cell is at or
//! above `presence_cost`: the presence band (or confirmed people) spans the
//! corridor from side to side there. A cell no camera sees is never present, so
//! a corridor partly out of view is never blocked where it is.

use isochron_config::CostmapConfig;

use super::RouteGraph;
use super::forecast::EdgeForecast;
use crate::cost::CostParams;
use crate::grid::{MapGrid, Point};
use crate::plan::{SegmentBlocks, SegmentCosts};
use crate::raster::{Footprint, NOT_SEEN};

/// A cost map cell as the bridge holds it: 0..=100, anything else unknown.
pub trait GridCell: Copy {
    /// The cell's cost, `None` if unknown (-1, 255 in a message's bytes).
    fn cost(self) -> Option<u8>;
}

impl GridCell for i8 {
    fn cost(self) -> Option<u8> {
        (0..=100).contains(&self).then_some(self as u8)
    }
}

impl GridCell for u8 {
    fn cost(self) -> Option<u8> {
        (self <= 100).then_some(self)
    }
}

/// The cells some camera sees (per cell of the grid; `footprints[k]`: camera
/// `k`'s, `None` without one; footprints of another grid are left out).
pub fn seen_cells(cells: usize, footprints: &[Option<&Footprint>]) -> Vec<bool> {
    let mut seen = vec![false; cells];
    for footprint in footprints.iter().flatten() {
        if footprint.cell_block.len() != cells {
            continue;
        }
        for (s, &b) in seen.iter_mut().zip(&footprint.cell_block) {
            *s |= b != NOT_SEEN;
        }
    }
    seen
}

/// The corridors of every edge of a graph on one grid.
#[derive(Debug, Clone)]
pub struct Corridors {
    grid: MapGrid,
    /// All corridors' cells; per edge its sections in order, then the rest.
    cells: Vec<u32>,
    /// Per edge `e`, its cells are `cells[edge_cells[e]..edge_cells[e + 1]]`.
    edge_cells: Vec<u32>,
    /// Per edge `e`, its sections are `section_end[edge_sections[e]..edge_sections[e + 1]]`.
    edge_sections: Vec<u32>,
    /// Per section, the end of its cells in `cells` (it starts where the previous
    /// section of its edge ended, or at its edge's first cell).
    section_end: Vec<u32>,
    /// Per edge, whether a camera sees a cell of its corridor.
    seen: Vec<bool>,
    /// Indices of the edges no camera sees.
    unseen: Vec<usize>,
}

/// One cell of a corridor as found: which section (or none) and where.
#[derive(Clone, Copy)]
struct Hit {
    section: u32,
    cell: u32,
}

/// A cell outside every section (caps, cut sections).
const NO_SECTION: u32 = u32::MAX;

impl Corridors {
    /// The corridors of `graph`'s edges on `grid`, `width_m` wide (an edge's
    /// `metadata.width_m` wins); `seen[cell]` says whether a camera sees it
    /// ([`seen_cells`]).
    pub fn build(graph: &RouteGraph, grid: &MapGrid, width_m: f64, seen: &[bool]) -> Corridors {
        let mut out = Corridors {
            grid: *grid,
            cells: Vec::new(),
            edge_cells: vec![0],
            edge_sections: vec![0],
            section_end: Vec::new(),
            seen: Vec::with_capacity(graph.edges().len()),
            unseen: Vec::new(),
        };
        for (e, edge) in graph.edges().iter().enumerate() {
            let half = edge.width_m.unwrap_or(width_m).max(0.0) / 2.0;
            let mut hits = rasterise(grid, &edge.line, half);
            hits.sort_unstable_by_key(|h| (h.section, h.cell));
            let is_seen = hits
                .iter()
                .any(|h| seen.get(h.cell as usize).copied().unwrap_or(false));
            let base = out.cells.len() as u32;
            for (k, h) in hits.iter().enumerate() {
                out.cells.push(h.cell);
                let last_of_section = hits.get(k + 1).is_none_or(|n| n.section != h.section);
                if h.section != NO_SECTION && last_of_section {
                    out.section_end.push(base + k as u32 + 1);
                }
            }
            out.edge_cells.push(out.cells.len() as u32);
            out.edge_sections.push(out.section_end.len() as u32);
            out.seen.push(is_seen);
            if !is_seen {
                out.unseen.push(e);
            }
        }
        out
    }

    /// The grid the corridors are on.
    pub fn grid(&self) -> &MapGrid {
        &self.grid
    }

    /// Number of edges.
    pub fn len(&self) -> usize {
        self.seen.len()
    }

    /// True for a graph without edges.
    pub fn is_empty(&self) -> bool {
        self.seen.is_empty()
    }

    /// The cells (row-major indices) of edge `edge`'s corridor.
    pub fn cells(&self, edge: usize) -> &[u32] {
        match (self.edge_cells.get(edge), self.edge_cells.get(edge + 1)) {
            (Some(&a), Some(&b)) => &self.cells[a as usize..b as usize],
            _ => &[],
        }
    }

    /// The cross-sections of edge `edge`, each its cells, in order along the edge.
    pub fn sections(&self, edge: usize) -> impl Iterator<Item = &[u32]> {
        let (a, b) = match (
            self.edge_sections.get(edge),
            self.edge_sections.get(edge + 1),
        ) {
            (Some(&a), Some(&b)) => (a as usize, b as usize),
            _ => (0, 0),
        };
        let mut start = self.edge_cells.get(edge).copied().unwrap_or(0) as usize;
        self.section_end[a..b].iter().map(move |&end| {
            let cells = &self.cells[start..end as usize];
            start = end as usize;
            cells
        })
    }

    /// True if a camera sees a cell of edge `edge`'s corridor.
    pub fn is_seen(&self, edge: usize) -> bool {
        self.seen.get(edge).copied().unwrap_or(false)
    }

    /// The edges (indices) no camera sees: never scored nor adjusted; the caller
    /// warns about them once.
    pub fn unseen(&self) -> &[usize] {
        &self.unseen
    }

    /// The blocks of each camera the corridor of edge `edge` covers, as a path
    /// segment named `edge <id>`: what the long-term model is read for
    /// ([`super::ModelForecast`]). `footprints[k]`: camera `k`'s footprint on its
    /// store's block grid.
    pub fn segment_blocks(
        &self,
        graph: &RouteGraph,
        edge: usize,
        footprints: &[Option<&Footprint>],
    ) -> SegmentBlocks {
        let cells = self.cells(edge);
        let mut blocks = Vec::new();
        for (k, footprint) in footprints.iter().enumerate() {
            let Some(footprint) = footprint else {
                continue;
            };
            let mut covered: Vec<u32> = cells
                .iter()
                .filter_map(|&c| footprint.cell_block.get(c as usize).copied())
                .filter(|&b| b != NOT_SEEN)
                .collect();
            covered.sort_unstable();
            covered.dedup();
            if !covered.is_empty() {
                blocks.push((k, covered));
            }
        }
        let id = graph.edges().get(edge).map_or(0, |e| e.id);
        SegmentBlocks {
            name: format!("edge {id}"),
            blocks,
        }
    }
}

/// The cells within `half` of `line`, with their cross-section.
fn rasterise(grid: &MapGrid, line: &[Point], half: f64) -> Vec<Hit> {
    let mut hits = Vec::new();
    let corners: Vec<Point> = line
        .iter()
        .flat_map(|p| {
            [
                [p[0] - half, p[1] - half],
                [p[0] + half, p[1] + half],
                [p[0] - half, p[1] + half],
                [p[0] + half, p[1] - half],
            ]
        })
        .collect();
    let Some((i0, j0, i1, j1)) = grid.bounds_of(&corners) else {
        return hits;
    };
    let pieces = Pieces::of(line);
    let res = grid.resolution;
    let sections = (pieces.length / res).ceil().max(1.0) as u32;
    let whole: Vec<bool> = (0..sections)
        .map(|k| section_is_whole(grid, &pieces, (k as f64 + 0.5) * res, half))
        .collect();
    for j in j0..=j1 {
        for i in i0..=i1 {
            let Some(near) = pieces.nearest(grid.cell_center(i, j)) else {
                continue;
            };
            if near.distance > half {
                continue;
            }
            let k = ((near.along / res) as u32).min(sections - 1);
            let section = if near.cap || !whole[k as usize] {
                NO_SECTION
            } else {
                k
            };
            hits.push(Hit {
                section,
                cell: grid.index(i, j) as u32,
            });
        }
    }
    hits
}

/// True if the cross-section at `along` metres along the line lies inside the grid
/// from side to side.
fn section_is_whole(grid: &MapGrid, pieces: &Pieces, along: f64, half: f64) -> bool {
    let (p, [dx, dy]) = pieces.at(along);
    let normal = [-dy, dx];
    [1.0, -1.0].iter().all(|side| {
        let q = [
            p[0] + side * normal[0] * half,
            p[1] + side * normal[1] * half,
        ];
        grid.cell_of(q).is_some()
    })
}

/// A line's straight pieces, with where each starts along the line.
struct Pieces {
    /// `(start, unit direction, length, metres along the line at its start)`.
    pieces: Vec<(Point, Point, f64, f64)>,
    length: f64,
}

/// Where a point's nearest point on a line is.
struct Nearest {
    distance: f64,
    along: f64,
    /// Beyond the line's first or last point.
    cap: bool,
}

impl Pieces {
    fn of(line: &[Point]) -> Pieces {
        let mut pieces = Vec::new();
        let mut along = 0.0;
        for w in line.windows(2) {
            let (dx, dy) = (w[1][0] - w[0][0], w[1][1] - w[0][1]);
            let length = dx.hypot(dy);
            let unit = if length > 0.0 {
                [dx / length, dy / length]
            } else {
                [1.0, 0.0]
            };
            pieces.push((w[0], unit, length, along));
            along += length;
        }
        Pieces {
            pieces,
            length: along,
        }
    }

    fn nearest(&self, c: Point) -> Option<Nearest> {
        let last = self.pieces.len().checked_sub(1)?;
        let mut best: Option<Nearest> = None;
        for (k, &(a, u, length, start)) in self.pieces.iter().enumerate() {
            let (vx, vy) = (c[0] - a[0], c[1] - a[1]);
            let t = vx * u[0] + vy * u[1];
            let cap = (k == 0 && t < 0.0) || (k == last && t > length);
            let t = t.clamp(0.0, length);
            let distance = (vx - t * u[0]).hypot(vy - t * u[1]);
            if best.as_ref().is_none_or(|b| distance < b.distance) {
                best = Some(Nearest {
                    distance,
                    along: start + t,
                    cap,
                });
            }
        }
        best
    }

    /// The point `along` metres along the line and the direction there.
    fn at(&self, along: f64) -> (Point, Point) {
        let piece = self
            .pieces
            .iter()
            .rev()
            .find(|p| p.3 <= along)
            .or(self.pieces.first());
        match piece {
            Some(&(a, u, length, start)) => {
                let t = (along - start).clamp(0.0, length);
                ([a[0] + t * u[0], a[1] + t * u[1]], u)
            }
            None => ([0.0, 0.0], [1.0, 0.0]),
        }
    }
}

/// An edge's state on a cost map.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EdgeScore {
    /// The edge's Cost2 (`w1 · Cost(M_e(t*)) + w2 · Cost(M_e(now))`, 0 to `(w1 +
    /// w2) · cap`); `None` when no camera sees its corridor (never adjusted).
    pub cost: Option<f64>,
    /// The presence band spans the corridor from side to side somewhere.
    pub blocked: bool,
    /// No cell of the corridor had a live cost: the long-term mean stood in.
    pub estimated: bool,
    /// The long-term model has no data for the corridor at t*.
    pub no_long_term: bool,
}

/// Scores edges: the cost function, the weights of Cost2 and the presence cost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeScorer {
    /// The cost function (`cost_scale`, `cap`, `presence_cost`).
    pub params: CostParams,
    /// Weight of the long-term cost.
    pub w1: f64,
    /// Weight of the short-term cost.
    pub w2: f64,
}

impl EdgeScorer {
    /// The scorer of `[costmap]`.
    pub fn from_config(c: &CostmapConfig) -> EdgeScorer {
        EdgeScorer {
            params: CostParams::from_config(c),
            w1: c.w1,
            w2: c.w2,
        }
    }

    /// Each edge's score (`out[e]` for edge `e`) from the live cost map `live`
    /// (the grid's cells, 0..=100, unknown otherwise; a map of another size counts
    /// as unknown everywhere) and the long-term `forecast` at `t_star`.
    ///
    /// `M_e(now)` is the mean activity of the corridor's known cells, a cell of
    /// cost `c` having activity `c · cost_scale / 100` (the inverse of `Cost`
    /// below `cap`; the live map also holds the `weight_long_term` part, the
    /// presence band and confirmed people, as the robots' costmap does);
    /// `M_e(t*)` is the forecast's. The cost is then [`SegmentCosts::cost2`].
    pub fn score<C: GridCell, F: EdgeForecast + ?Sized>(
        &self,
        corridors: &Corridors,
        live: &[C],
        forecast: &F,
        t_star: u32,
        out: &mut Vec<EdgeScore>,
    ) {
        out.clear();
        out.resize(corridors.len(), EdgeScore::default());
        let live = if live.len() == corridors.grid.len() {
            live
        } else {
            &[]
        };
        let presence = self.params.presence_cost;
        for (e, score) in out.iter_mut().enumerate() {
            if !corridors.is_seen(e) {
                continue;
            }
            let (mut sum, mut n, mut blocked) = (0u64, 0u64, false);
            let mut add = |cells: &[u32]| {
                let mut all = !cells.is_empty();
                for &c in cells {
                    match live.get(c as usize).and_then(|v| v.cost()) {
                        Some(v) => {
                            sum += v as u64;
                            n += 1;
                            all &= v >= presence;
                        }
                        None => all = false,
                    }
                }
                all
            };
            let mut in_sections = 0;
            for section in corridors.sections(e) {
                blocked |= add(section);
                in_sections += section.len();
            }
            add(&corridors.cells(e)[in_sections..]);
            let now = (n > 0).then(|| sum as f64 / n as f64 * self.params.cost_scale / 100.0);
            let costs = SegmentCosts::of(forecast.activity(e, t_star), now, &self.params);
            *score = EdgeScore {
                cost: Some(costs.cost2(self.w1, self.w2)),
                blocked,
                estimated: costs.estimated,
                no_long_term: costs.no_long_term,
            };
        }
    }
}
