//! The global light change: the gain and offset that map the empty scene's
//! appearance to this second's, fitted over the empty, still blocks.

/// The global fit needs at least this many empty, still blocks.
pub(super) const FIT_MIN_BLOCKS: usize = 8;

/// The global light change `a = g·B + c` from `(B, a)` pairs of empty blocks: a
/// first line through the medians of the darker and the brighter half, then least
/// squares over the pairs near that line (what differs for another reason — a
/// shadow, someone the band missed — is left out). A gain alone (`c = 0`) when the
/// blocks are too alike in brightness to tell an offset from a gain. `g` is kept
/// within 0.2..=5.
pub(super) fn fit_light(pairs: &mut [(f32, f32)]) -> (f32, f32) {
    // The darker and the brighter half (by B), each in no order.
    let half = pairs.len() / 2;
    pairs.select_nth_unstable_by(half, |a, b| a.0.total_cmp(&b.0));
    let (b_lo, a_lo) = medians(&mut pairs[..half]);
    let (b_hi, a_hi) = medians(&mut pairs[half..]);
    let spread = b_hi - b_lo >= 16.0;
    let (gain, offset) = if spread {
        let gain = ((a_hi - a_lo) / (b_hi - b_lo)).clamp(0.2, 5.0);
        (gain, a_lo - gain * b_lo)
    } else {
        let (b, a) = medians(pairs);
        if b > 1.0 {
            ((a / b).clamp(0.2, 5.0), 0.0)
        } else {
            return (1.0, a - b);
        }
    };
    // Refine on the inliers: within 8 grey levels (or 10 %) of the first line.
    let (mut n, mut sb, mut sa, mut sbb, mut sba) = (0.0f64, 0.0f64, 0.0, 0.0, 0.0);
    for &(b, a) in pairs.iter() {
        let predicted = gain * b + offset;
        if (a - predicted).abs() <= 8.0f32.max(0.1 * predicted) {
            let (b, a) = (b as f64, a as f64);
            n += 1.0;
            sb += b;
            sa += a;
            sbb += b * b;
            sba += b * a;
        }
    }
    if n < FIT_MIN_BLOCKS as f64 {
        return (gain, offset);
    }
    if !spread {
        return if sbb > 0.0 {
            (((sba / sbb) as f32).clamp(0.2, 5.0), 0.0)
        } else {
            (gain, offset)
        };
    }
    let det = n * sbb - sb * sb;
    if det <= 0.0 {
        return (gain, offset);
    }
    let g = (((n * sba - sb * sa) / det) as f32).clamp(0.2, 5.0);
    (g, ((sa - g as f64 * sb) / n) as f32)
}

/// The medians of both coordinates of `pairs` (reordered).
fn medians(pairs: &mut [(f32, f32)]) -> (f32, f32) {
    if pairs.is_empty() {
        return (0.0, 0.0);
    }
    let mid = pairs.len() / 2;
    let b = pairs
        .select_nth_unstable_by(mid, |x, y| x.0.total_cmp(&y.0))
        .1
        .0;
    let a = pairs
        .select_nth_unstable_by(mid, |x, y| x.1.total_cmp(&y.1))
        .1
        .1;
    (b, a)
}
