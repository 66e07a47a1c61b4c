//! The long-term activity of a set of blocks over the isochronal cycle: per bin
//! (minute of the day, or of the week), the mean over the blocks of their learned
//! means, the typical day-to-day spread, and how many days taught it.
//!
//! One computation for every reader of the long-term stores: a path segment's
//! `M_p(t*)` ([`crate::plan::SegmentProfile`]), `isochron store export` and
//! `isochron plot daily` (all blocks of a camera, one block, or a segment).

use std::ops::Deref;

use isochron_store::{Bin, Model};

/// One bin of a profile.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProfilePoint {
    /// Minute of the cycle.
    pub t_star: u32,
    /// Mean over the blocks of their long-term means, negatives counted as 0 and
    /// non-finite means left out (`None`: no block has learned this bin).
    pub mean: Option<f64>,
    /// Root mean square of the blocks' sigmas (`None`: never taught).
    pub sigma: Option<f64>,
    /// Days (cycles) that taught the bin: the most over the models.
    pub count: u32,
}

/// The profile of `blocks` over `bins` bins of the cycle: for each `(model,
/// block indices)` the blocks (row-major indices into that model's grid) of one
/// camera. A model of a shorter cycle repeats (a daily store serves every day of a
/// weekly cycle); bins that taught nothing (absent, or a count of 0) contribute
/// nothing.
///
/// Long-term means are activity densities, never below zero: a negative mean
/// (rounding in the running variance update) counts as 0.
pub fn daily_profile(blocks: &[(&Model, &[u32])], bins: usize) -> Vec<ProfilePoint> {
    (0..bins).map(|t| profile_at(blocks, t as u32)).collect()
}

/// One bin of [`daily_profile`]: the profile of `blocks` at minute `t_star` of the
/// cycle.
pub fn profile_at(blocks: &[(&Model, &[u32])], t_star: u32) -> ProfilePoint {
    point_of(
        t_star,
        blocks.iter().filter_map(|(model, indices)| {
            let bin = model
                .bin(t_star % model.meta.bins().max(1))
                .filter(|b| b.count > 0)?;
            Some((bin, *indices))
        }),
    )
}

/// The profile point at `t_star` of the blocks `indices` of each bin of `bins`
/// (one per camera: its bin at `t_star`, taught at least once).
pub fn point_of<'a, B: Deref<Target = Bin>>(
    t_star: u32,
    bins: impl IntoIterator<Item = (B, &'a [u32])>,
) -> ProfilePoint {
    let (mut sum, mut n) = (0.0f64, 0usize);
    let (mut sum_var, mut n_var) = (0.0f64, 0usize);
    let mut count = 0;
    for (bin, indices) in bins {
        count = count.max(bin.count);
        for &b in indices {
            if let Some(&m) = bin.mean.get(b as usize)
                && m.is_finite()
            {
                sum += (m as f64).max(0.0);
                n += 1;
            }
            sum_var += bin.var.get(b as usize).map_or(0.0, |v| v.max(0.0) as f64);
            n_var += 1;
        }
    }
    ProfilePoint {
        t_star,
        mean: (n > 0).then(|| sum / n as f64),
        sigma: (n_var > 0).then(|| (sum_var / n_var as f64).sqrt()),
        count,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_config::clock::Cycle;
    use isochron_store::{Bin, StoreMeta};
    use isochron_wire::geometry::BlockGrid;

    fn model(cycle: Cycle, t: u32, count: u32, mean: Vec<f32>, var: Vec<f32>) -> Model {
        let meta = StoreMeta::new("c", BlockGrid::new(32, 32, 16), cycle, 0);
        let bin = Bin {
            t_star: t,
            count,
            last_minute: 0,
            mean,
            var,
        };
        Model::with_bins(meta, [bin])
    }

    #[test]
    fn means_are_averaged_and_sigmas_root_mean_squared() {
        let m = model(
            Cycle::Daily,
            5,
            3,
            vec![1.0, 2.0, 3.0, 6.0],
            vec![1.0, 1.0, 4.0, 4.0],
        );
        let all = daily_profile(&[(&m, &[0, 1, 2, 3])], 1440);
        assert_eq!(all.len(), 1440);
        assert_eq!(all[5].mean, Some(3.0));
        assert_eq!(all[5].sigma, Some(2.5f64.sqrt()));
        assert_eq!(all[5].count, 3);
        assert_eq!((all[4].mean, all[4].sigma, all[4].count), (None, None, 0));
        let one = daily_profile(&[(&m, &[3])], 1440);
        assert_eq!((one[5].mean, one[5].sigma), (Some(6.0), Some(2.0)));
    }

    #[test]
    fn negatives_count_as_zero_and_non_finite_means_are_left_out() {
        let m = model(
            Cycle::Daily,
            7,
            2,
            vec![-0.5, 0.5, f32::NAN, 1.0],
            vec![0.0, -1.0, 0.0, 0.0],
        );
        let p = daily_profile(&[(&m, &[0, 1, 2, 3])], 1440);
        assert_eq!(p[7].mean, Some(0.5));
        assert_eq!(p[7].sigma, Some(0.0));
    }

    #[test]
    fn models_are_pooled_and_a_daily_model_repeats_over_a_week() {
        let a = model(Cycle::Daily, 10, 4, vec![0.2; 4], vec![0.0; 4]);
        let b = model(Cycle::Weekly, 1440 + 10, 1, vec![0.4; 4], vec![0.0; 4]);
        let p = daily_profile(&[(&a, &[0]), (&b, &[0, 1, 2])], 10080);
        assert_eq!(p.len(), 10080);
        assert!(
            (p[10].mean.unwrap() - 0.2).abs() < 1e-6,
            "b has not learned day 0"
        );
        assert!((p[1440 + 10].mean.unwrap() - 0.35).abs() < 1e-6);
        assert_eq!(p[1440 + 10].count, 4);
        let untaught = model(Cycle::Daily, 3, 0, vec![1.0; 4], vec![0.0; 4]);
        assert_eq!(daily_profile(&[(&untaught, &[0])], 1440)[3].mean, None);
    }
}
