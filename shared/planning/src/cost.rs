//! From activity to cost: the weighted activity of a block, the 0..=100 cost it
//! gives, and the cost map composed from every camera.
//!
//! `Cost(a) = min(cap, 100 · a / cost_scale)` for an activity `a` in density units
//! (the mean motion density per block that the cascade reports). On the map,
//! `a = weight_in_place·S1 + weight_moving·S2 + weight_long_term·M(t*)` per block, the
//! cost is rounded to an integer, a cell takes the highest cost of the cameras that
//! see it and -1 where none does, and a person the detector confirmed raises the
//! cells around their feet to at least `confirm_cost`; a block of the presence
//! band (something that entered and stays, moving or not) gives its cells at
//! least `presence_cost`. For planning, `Cost` is applied unrounded to a
//! segment's activity `M_p`.

use isochron_config::CostmapConfig;
use isochron_wire::BlockActivity;

use crate::grid::MapGrid;
use crate::raster::{Footprint, NOT_SEEN};

/// Value of a cell no camera sees.
pub const UNKNOWN: i8 = -1;

/// The parameters of the cost function.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CostParams {
    /// Weight of in-place activity S1.
    pub weight_in_place: f64,
    /// Weight of moving activity S2.
    pub weight_moving: f64,
    /// Weight of the long-term mean M(t*).
    pub weight_long_term: f64,
    /// Activity that costs 100.
    pub cost_scale: f64,
    /// Highest cost from activity, 1..=100.
    pub cap: u8,
    /// Cost around a confirmed person, 0..=100.
    pub confirm_cost: u8,
    /// Radius around a confirmed person's feet, metres.
    pub confirm_radius_m: f64,
    /// Least cost of a present block, 0..=100.
    pub presence_cost: u8,
}

impl CostParams {
    /// The parameters of `[costmap]`.
    pub fn from_config(c: &CostmapConfig) -> CostParams {
        CostParams {
            weight_in_place: c.weight_in_place,
            weight_moving: c.weight_moving,
            weight_long_term: c.weight_long_term,
            cost_scale: c.cost_scale,
            cap: c.cap.min(100),
            confirm_cost: c.confirm_cost().min(100),
            confirm_radius_m: c.confirm_radius_m,
            presence_cost: c.presence_cost().min(100),
        }
    }

    /// The weighted activity of a block on the map (negative or non-finite parts,
    /// which a sane producer never sends, count as 0).
    pub fn block_activity(&self, b: &BlockActivity) -> f64 {
        let part = |w: f64, v: f32| {
            let v = v as f64;
            if v.is_finite() && v > 0.0 { w * v } else { 0.0 }
        };
        part(self.weight_in_place, b.s1)
            + part(self.weight_moving, b.s2)
            + part(self.weight_long_term, b.lt_mean)
    }

    /// The short-term activity of a block, as real-time planning sees it
    /// (`weight_in_place·S1 + weight_moving·S2`).
    pub fn short_term_activity(&self, b: &BlockActivity) -> f64 {
        let part = |w: f64, v: f32| {
            let v = v as f64;
            if v.is_finite() && v > 0.0 { w * v } else { 0.0 }
        };
        part(self.weight_in_place, b.s1) + part(self.weight_moving, b.s2)
    }

    /// `Cost(a)`, unrounded: 0 ..= cap.
    pub fn cost_of(&self, activity: f64) -> f64 {
        if !(activity.is_finite() && activity > 0.0) {
            return 0.0;
        }
        (100.0 * activity / self.cost_scale).min(self.cap as f64)
    }

    /// `Cost(a)` as a cell value.
    pub fn cell_cost(&self, activity: f64) -> i8 {
        self.cost_of(activity).round() as i8
    }

    /// A block's cell value on the map: the cost of its activity, at least
    /// `presence_cost` while the block is present.
    pub fn block_cost(&self, b: &BlockActivity) -> i8 {
        let cost = self.cell_cost(self.block_activity(b));
        if b.present >= 0.5 {
            cost.max(self.presence_cost as i8)
        } else {
            cost
        }
    }
}

/// One camera's contribution: its footprint and its latest block activity.
#[derive(Debug, Clone, Copy)]
pub struct Layer<'a> {
    /// Cells per block.
    pub footprint: &'a Footprint,
    /// Activity per block (as many as the footprint's block grid has).
    pub blocks: &'a [BlockActivity],
}

/// The cost map: every seen cell's cost, the highest over cameras; -1 where none
/// sees; then confirmed people (`confirmed`, feet on the floor) raise their
/// surroundings.
pub fn compose(
    grid: &MapGrid,
    params: &CostParams,
    layers: &[Layer<'_>],
    confirmed: &[[f64; 2]],
) -> Vec<i8> {
    let mut cells = vec![UNKNOWN; grid.len()];
    for layer in layers {
        if layer.footprint.cell_block.len() != cells.len() {
            continue;
        }
        let block_cost: Vec<i8> = layer.blocks.iter().map(|b| params.block_cost(b)).collect();
        for (cell, &b) in cells.iter_mut().zip(&layer.footprint.cell_block) {
            if b == NOT_SEEN {
                continue;
            }
            if let Some(&c) = block_cost.get(b as usize) {
                *cell = (*cell).max(c);
            }
        }
    }
    let confirm = params.confirm_cost as i8;
    for feet in confirmed {
        let r = params.confirm_radius_m;
        let corners = [
            [feet[0] - r, feet[1] - r],
            [feet[0] + r, feet[1] - r],
            [feet[0] + r, feet[1] + r],
            [feet[0] - r, feet[1] + r],
        ];
        let Some((i0, j0, i1, j1)) = grid.bounds_of(&corners) else {
            continue;
        };
        for j in j0..=j1 {
            for i in i0..=i1 {
                let c = grid.cell_center(i, j);
                if (c[0] - feet[0]).hypot(c[1] - feet[1]) <= r.max(grid.resolution / 2.0) {
                    let k = grid.index(i, j);
                    cells[k] = cells[k].max(confirm);
                }
            }
        }
    }
    cells
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_wire::geometry::BlockGrid;

    fn params() -> CostParams {
        CostParams {
            weight_in_place: 1.0,
            weight_moving: 0.5,
            weight_long_term: 0.25,
            cost_scale: 0.2,
            cap: 90,
            confirm_cost: 100,
            confirm_radius_m: 0.25,
            presence_cost: 60,
        }
    }

    fn activity(s1: f32, s2: f32, lt: f32) -> BlockActivity {
        BlockActivity {
            s1,
            s2,
            lt_mean: lt,
            ..Default::default()
        }
    }

    #[test]
    fn cost_weights_scales_and_caps() {
        let p = params();
        // 1·0.02 + 0.5·0.04 + 0.25·0.08 = 0.06 → 100·0.06/0.2 = 30.
        let a = p.block_activity(&activity(0.02, 0.04, 0.08));
        assert!((a - 0.06).abs() < 1e-7, "{a}");
        assert_eq!(p.cell_cost(a), 30);
        assert_eq!(p.cell_cost(0.0), 0);
        // Above the scale: capped at 90, not 100.
        assert_eq!(p.cell_cost(p.block_activity(&activity(1.0, 0.0, 0.0))), 90);
        // Garbage counts as no activity.
        assert_eq!(
            p.block_activity(&activity(f32::NAN, -1.0, f32::INFINITY)),
            0.0
        );
        assert_eq!(p.cost_of(f64::NAN), 0.0);
        // Short-term activity leaves the long-term mean out.
        assert!((p.short_term_activity(&activity(0.02, 0.04, 0.08)) - 0.04).abs() < 1e-7);
        // A present block costs at least presence_cost, more if its activity says so.
        let present = |s1| BlockActivity {
            present: 1.0,
            ..activity(s1, 0.0, 0.0)
        };
        assert_eq!(p.block_cost(&present(0.0)), 60);
        assert_eq!(p.block_cost(&present(1.0)), 90);
        assert_eq!(p.block_cost(&activity(0.0, 0.0, 0.0)), 0);
    }

    #[test]
    fn cells_take_the_highest_camera_and_unknown_elsewhere() {
        let grid = MapGrid {
            origin_x: 0.0,
            origin_y: 0.0,
            yaw: 0.0,
            resolution: 1.0,
            width: 3,
            height: 1,
        };
        let blocks = BlockGrid {
            frame_width: 32,
            frame_height: 16,
            block_px: 16,
        };
        let a = Footprint {
            blocks,
            cell_block: vec![0, 1, NOT_SEEN],
            seen: 2,
        };
        let b = Footprint {
            blocks,
            cell_block: vec![NOT_SEEN, 0, NOT_SEEN],
            seen: 1,
        };
        let acts_a = [activity(0.02, 0.0, 0.0), activity(0.01, 0.0, 0.0)];
        let acts_b = [activity(0.1, 0.0, 0.0), activity(0.0, 0.0, 0.0)];
        let cells = compose(
            &grid,
            &params(),
            &[
                Layer {
                    footprint: &a,
                    blocks: &acts_a,
                },
                Layer {
                    footprint: &b,
                    blocks: &acts_b,
                },
            ],
            &[],
        );
        assert_eq!(cells, vec![10, 50, UNKNOWN]);
        // A confirmed person at the third cell's centre raises it (and only it).
        let cells = compose(
            &grid,
            &params(),
            &[Layer {
                footprint: &a,
                blocks: &acts_a,
            }],
            &[[2.5, 0.5]],
        );
        assert_eq!(cells, vec![10, 5, 100]);
    }
}
