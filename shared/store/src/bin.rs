//! One bin of the long-term model: a row of the store, or a forecast read from rows.

/// The long-term model of one minute bin: per block the exponentially weighted mean
/// and variance of the minute means of `M_L1`. A row of the store, or a forecast
/// read from rows ([`crate::isochronal::Rules::forecast`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Bin {
    /// The row of the store (with the daily and weekly cycles, and the weekday rows
    /// of day types, the minute t* of the cycle); in a forecast, t*.
    pub t_star: u32,
    /// Minutes (one per day, or per week for a weekday's row) that taught this bin.
    /// All blocks of a bin learn together, so this is every block's count.
    pub count: u32,
    /// Absolute minute (minutes since the Unix epoch) that last taught this bin.
    pub last_minute: i64,
    /// Mean per block (row-major), density units.
    pub mean: Vec<f32>,
    /// Variance per block.
    pub var: Vec<f32>,
}

impl Bin {
    /// A bin that has learned nothing yet.
    pub fn empty(t_star: u32, blocks: usize) -> Bin {
        Bin {
            t_star,
            count: 0,
            last_minute: i64::MIN,
            mean: vec![0.0; blocks],
            var: vec![0.0; blocks],
        }
    }

    /// Standard deviation of block `k` (0 outside the grid).
    pub fn sigma(&self, k: usize) -> f32 {
        self.var.get(k).map_or(0.0, |v| v.max(0.0).sqrt())
    }

    /// Mean of the block means.
    pub fn mean_over_blocks(&self) -> f64 {
        if self.mean.is_empty() {
            return 0.0;
        }
        self.mean.iter().map(|&m| m as f64).sum::<f64>() / self.mean.len() as f64
    }

    /// Mean of the block variances.
    pub fn var_over_blocks(&self) -> f64 {
        if self.var.is_empty() {
            return 0.0;
        }
        self.var.iter().map(|&m| m as f64).sum::<f64>() / self.var.len() as f64
    }
}
