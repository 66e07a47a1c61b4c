//! What the long-term model expects on each edge: `M_e(t*)`, the mean long-term
//! activity of the blocks its corridor covers, as a path segment's `M_p(t*)`
//! ([`crate::profile`]).

use std::collections::HashMap;

use isochron_store::{Bin, Model};

use crate::plan::SegmentBlocks;
use crate::profile::{point_of, profile_at};

/// The long-term activity expected on each edge of a graph over the cycle.
pub trait EdgeForecast {
    /// `M_e(t*)`: the mean long-term activity of edge `edge` (an index of the
    /// graph's edges) at minute `t_star` of the cycle; `None` where nothing was
    /// learned or no camera sees the edge.
    fn activity(&self, edge: usize, t_star: u32) -> Option<f64>;

    /// Minutes in the cycle: 1440 (daily) or 10080 (a week).
    fn cycle_minutes(&self) -> u32;
}

/// A forecast that knows nothing (every edge unknown at every t*).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NoForecast {
    /// Minutes in the cycle.
    pub cycle_minutes: u32,
}

impl EdgeForecast for NoForecast {
    fn activity(&self, _edge: usize, _t_star: u32) -> Option<f64> {
        None
    }

    fn cycle_minutes(&self) -> u32 {
        self.cycle_minutes
    }
}

/// A forecast given by a function `(edge, t*) → M_e(t*)`.
#[derive(Debug, Clone, Copy)]
pub struct FnForecast<F> {
    /// Minutes in the cycle.
    pub cycle_minutes: u32,
    /// `M_e(t*)`.
    pub activity: F,
}

impl<F: Fn(usize, u32) -> Option<f64>> EdgeForecast for FnForecast<F> {
    fn activity(&self, edge: usize, t_star: u32) -> Option<f64> {
        (self.activity)(edge, t_star)
    }

    fn cycle_minutes(&self) -> u32 {
        self.cycle_minutes
    }
}

/// The forecast of the cameras' long-term models: per edge, its blocks
/// ([`super::Corridors::segment_blocks`]) averaged as [`profile_at`] averages a
/// segment's. Reading a model's bin can blend rows (rest days, holidays), so the
/// bins of the minutes a query needs are read once ([`ModelForecast::read`]);
/// other minutes are read on each call.
pub struct ModelForecast<'a> {
    cycle_minutes: u32,
    /// Per edge, `(camera, blocks)`.
    edges: Vec<Vec<(usize, &'a [u32])>>,
    models: Vec<Option<&'a Model>>,
    /// Per minute read, per camera, its bin (taught at least once).
    bins: HashMap<u32, Vec<Option<Bin>>>,
}

impl<'a> ModelForecast<'a> {
    /// The forecast of `edges` (per edge, its blocks) from `models` (camera `k`'s
    /// at `k`, `None` without a store) over a cycle of `cycle_minutes`.
    pub fn new(
        edges: &'a [SegmentBlocks],
        models: &[Option<&'a Model>],
        cycle_minutes: u32,
    ) -> ModelForecast<'a> {
        ModelForecast {
            cycle_minutes: cycle_minutes.max(1),
            edges: edges
                .iter()
                .map(|s| s.blocks.iter().map(|(k, b)| (*k, b.as_slice())).collect())
                .collect(),
            models: models.to_vec(),
            bins: HashMap::new(),
        }
    }

    /// Reads the models' bins of the minutes `t_stars` once, for the calls to come,
    /// forgetting those read before (so that a long-running caller holds only the
    /// minutes it needs: the current one to score, a window's to plan).
    pub fn read(&mut self, t_stars: impl IntoIterator<Item = u32>) {
        self.bins.clear();
        for t in t_stars {
            let t = t % self.cycle_minutes;
            if self.bins.contains_key(&t) {
                continue;
            }
            let bins = self
                .models
                .iter()
                .map(|m| {
                    let model = (*m)?;
                    let bin = model.bin(t % model.meta.bins().max(1))?;
                    (bin.count > 0).then(|| bin.into_owned())
                })
                .collect();
            self.bins.insert(t, bins);
        }
    }
}

impl EdgeForecast for ModelForecast<'_> {
    fn activity(&self, edge: usize, t_star: u32) -> Option<f64> {
        let blocks = self.edges.get(edge)?;
        let t = t_star % self.cycle_minutes;
        if let Some(bins) = self.bins.get(&t) {
            let pairs = blocks
                .iter()
                .filter_map(|&(k, b)| Some((bins.get(k)?.as_ref()?, b)));
            return point_of(t, pairs).mean;
        }
        let pairs: Vec<(&Model, &[u32])> = blocks
            .iter()
            .filter_map(|&(k, b)| Some((self.models.get(k).copied().flatten()?, b)))
            .collect();
        profile_at(&pairs, t).mean
    }

    fn cycle_minutes(&self) -> u32 {
        self.cycle_minutes
    }
}
