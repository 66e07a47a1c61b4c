//! `[cascade]`: the cascade of temporal filters and the long-term model.

use serde::{Deserialize, Serialize};

use super::{Invalid, check_positive, check_range};

/// `[cascade]`: the cascade of temporal filters (docs/ARCHITECTURE.md, "Filters"). Filters are
/// configured by their 10 %-decay duration T and rate r; α = 0.1^(1/(r·T)).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CascadeConfig {
    /// T of F_L1, the high-pass at frame rate, seconds. Default 1800 (30 min).
    pub t_l1_s: f64,
    /// T of F_L2, the isochronal low-pass, in cycles (days). Default 10.
    pub t_l2_days: f64,
    /// T of F_S1, the in-place low-pass at 1 Hz, seconds. Default 20.
    pub t_s1_s: f64,
    /// Frame rate r for F_L1 (frames/s); default: measured from header timestamps.
    pub frame_rate: Option<f64>,
    /// Isochronal cycle: `"daily"` (default) or `"weekly"`.
    pub cycle: crate::clock::Cycle,
    /// A minute updates F_L2 only if it got at least this fraction of the frames
    /// expected at rate r (gaps teach nothing). Default 0.8.
    pub min_coverage: f64,
    /// Days of data a minute bin needs before the long-term model counts as warm.
    /// Default 3.
    pub warm_days: u32,
}

impl Default for CascadeConfig {
    fn default() -> Self {
        CascadeConfig {
            t_l1_s: 1800.0,
            t_l2_days: 10.0,
            t_s1_s: 20.0,
            frame_rate: None,
            cycle: crate::clock::Cycle::Daily,
            min_coverage: 0.8,
            warm_days: 3,
        }
    }
}

impl CascadeConfig {
    /// Checks the `cascade.*` keys.
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        check_positive("cascade.t_l1_s", self.t_l1_s)?;
        check_positive("cascade.t_l2_days", self.t_l2_days)?;
        check_positive("cascade.t_s1_s", self.t_s1_s)?;
        if let Some(r) = self.frame_rate {
            check_range("cascade.frame_rate", r, 0.01, 1000.0)?;
        }
        check_range("cascade.min_coverage", self.min_coverage, 0.0, 1.0)
    }
}
