//! From a block's integer sums to its wire features: density, the flow vector
//! (dx, dy) and the 8-way direction label.
//!
//! * **density** `= weight / (GRADIENT_SATURATION × pixels)`: the block's motion
//!   pixels weighted by their gradient, normalised so that a block whose every pixel
//!   moves across a strong edge has density 1;
//! * **direction**: the Lucas–Kanade displacement `d = 4·T⁻¹·b` of the block (`T` the
//!   structure tensor, `b = (flow_x, flow_y)` the summed normal flow) when `T` is well
//!   conditioned — smaller eigenvalue at least [`MIN_EIGEN_RATIO`] of the larger:
//!   texture in more than one orientation. Otherwise the block sees a single edge and
//!   only the flow normal to it is knowable (the aperture problem): the direction is
//!   `b`, the mean normal flow;
//! * **coherence** `= R²`, the fraction of the block's temporal change `Σ It²` that
//!   this one displacement explains (`bᵀ·T⁻¹·b / Σ It²`; for an edge, the same along
//!   its normal): 1 when every motion pixel moves the same way, near 0 for noise, a
//!   lighting change, or two people crossing in one block;
//! * **flow vector** `(dx, dy) = density × coherence × unit(direction)`: how much and
//!   how coherently the block moves, and where to. It is carried as a vector through
//!   every filter (an average of angles is wrong at the wrap-around); the label is
//!   derived last.

use isochron_wire::{BlockMotion, DIRECTION_NONE};

use crate::kernel::{BlockSums, GRADIENT_SATURATION};

/// Least coherence (R²) for a moving block to get a direction label; below it the
/// block moves but in no particular direction (`DIRECTION_NONE`).
pub const MIN_COHERENCE: f32 = 0.2;

/// Least ratio of the structure tensor's eigenvalues for the Lucas–Kanade solve;
/// below it the block is treated as an edge and its normal flow is used.
pub const MIN_EIGEN_RATIO: f64 = 0.05;

/// The motion that best explains a block's temporal change.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fit {
    /// Direction vector, x right (Lucas–Kanade displacement in pixels per frame, or
    /// the summed normal flow for an edge).
    pub vx: f64,
    /// Direction vector, y down.
    pub vy: f64,
    /// R²: fraction of `Σ It²` explained, 0..=1.
    pub coherence: f64,
    /// Displacement, pixels per frame, when the block had texture in two orientations.
    pub speed_px: Option<f64>,
}

/// Fits one displacement to a block's sums (see the module documentation); `None`
/// when there is nothing to fit.
pub fn fit(sums: &BlockSums) -> Option<Fit> {
    let (a, b, c) = (sums.gxx as f64, sums.gxy as f64, sums.gyy as f64);
    let (fx, fy) = (sums.flow_x as f64, sums.flow_y as f64);
    let it2 = sums.it2 as f64;
    if it2 <= 0.0 || (fx == 0.0 && fy == 0.0) {
        return None;
    }
    let half = (a + c) / 2.0;
    let det = a * c - b * b;
    let spread = (half * half - det).max(0.0).sqrt();
    let (l1, l2) = (half + spread, half - spread);
    if l1 <= 0.0 {
        return None;
    }
    if det > 0.0 && l2 >= MIN_EIGEN_RATIO * l1 {
        // u = T⁻¹·b; explained = bᵀ·u; d = 4·u.
        let (ux, uy) = ((c * fx - b * fy) / det, (a * fy - b * fx) / det);
        let explained = fx * ux + fy * uy;
        return Some(Fit {
            vx: 4.0 * ux,
            vy: 4.0 * uy,
            coherence: (explained / it2).clamp(0.0, 1.0),
            speed_px: Some(4.0 * (ux * ux + uy * uy).sqrt()),
        });
    }
    // An edge: regress along the dominant gradient orientation e1 only.
    let (ex, ey) = if b != 0.0 {
        (l1 - c, b)
    } else if a >= c {
        (1.0, 0.0)
    } else {
        (0.0, 1.0)
    };
    let along = (fx * ex + fy * ey) / (ex * ex + ey * ey).sqrt();
    Some(Fit {
        vx: fx,
        vy: fy,
        coherence: (along * along / (l1 * it2)).clamp(0.0, 1.0),
        speed_px: None,
    })
}

/// Density, coherence and unit direction of one block.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Features {
    /// 0..=1.
    pub density: f32,
    /// 0..=1.
    pub coherence: f32,
    /// Unit vector of the flow, x right; (0, 0) when there is none.
    pub ux: f32,
    /// Unit vector of the flow, y down.
    pub uy: f32,
    /// Lucas–Kanade speed, pixels per frame, when the block had texture in two
    /// orientations (diagnostics; not on the wire).
    pub speed_px: Option<f32>,
}

impl Features {
    /// Features of a block of `area` pixels with `sums`.
    pub fn from_sums(sums: &BlockSums, area: usize) -> Features {
        if area == 0 || sums.weight == 0 {
            return Features::default();
        }
        let density =
            (sums.weight as f64 / (GRADIENT_SATURATION as f64 * area as f64)).min(1.0) as f32;
        let still = Features {
            density,
            ..Features::default()
        };
        let Some(fit) = fit(sums) else {
            return still;
        };
        let len = (fit.vx * fit.vx + fit.vy * fit.vy).sqrt();
        if len == 0.0 || !len.is_finite() {
            return still;
        }
        Features {
            density,
            coherence: fit.coherence as f32,
            ux: (fit.vx / len) as f32,
            uy: (fit.vy / len) as f32,
            speed_px: fit.speed_px.map(|v| v as f32),
        }
    }

    /// The wire form; the direction label is given when `density ≥
    /// density_threshold` and `coherence ≥ MIN_COHERENCE`.
    pub fn to_block(self, density_threshold: f32) -> BlockMotion {
        let k = self.density * self.coherence;
        let (dx, dy) = (k * self.ux, k * self.uy);
        let labelled = self.density >= density_threshold
            && self.coherence >= MIN_COHERENCE
            && (self.ux != 0.0 || self.uy != 0.0);
        BlockMotion {
            density: self.density,
            dx,
            dy,
            direction: if labelled {
                direction_label(self.ux, self.uy)
            } else {
                DIRECTION_NONE
            },
            ..BlockMotion::default()
        }
    }
}

/// The 8-way label of the screen vector `(dx, dy)` (y down): 0 = right, counting
/// counter-clockwise on screen in steps of 45° (2 = up, 4 = left, 6 = down);
/// [`DIRECTION_NONE`] for the zero vector.
pub fn direction_label(dx: f32, dy: f32) -> u8 {
    if dx == 0.0 && dy == 0.0 || !dx.is_finite() || !dy.is_finite() {
        return DIRECTION_NONE;
    }
    // The nearest multiple of 45° to atan2(−dy, dx), by comparisons with
    // tan(22.5°) instead of an arc tangent.
    const TAN_22_5: f32 = 0.414_213_57;
    let (x, y) = (dx, -dy); // counter-clockwise on screen
    let (ax, ay) = (x.abs(), y.abs());
    if ay <= TAN_22_5 * ax {
        if x > 0.0 { 0 } else { 4 }
    } else if ax <= TAN_22_5 * ay {
        if y > 0.0 { 2 } else { 6 }
    } else {
        match (x > 0.0, y > 0.0) {
            (true, true) => 1,
            (false, true) => 3,
            (false, false) => 5,
            (true, false) => 7,
        }
    }
}

/// The unit vector of label `direction` (screen coordinates, y down), `None` for
/// [`DIRECTION_NONE`] or an unknown label.
pub fn label_vector(direction: u8) -> Option<(f32, f32)> {
    if direction >= 8 {
        return None;
    }
    let angle = direction as f32 * std::f32::consts::FRAC_PI_4;
    Some((angle.cos(), -angle.sin()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_follow_the_wire_convention() {
        assert_eq!(direction_label(1.0, 0.0), 0);
        assert_eq!(direction_label(1.0, -1.0), 1); // up-right
        assert_eq!(direction_label(0.0, -1.0), 2); // up
        assert_eq!(direction_label(-1.0, -1.0), 3);
        assert_eq!(direction_label(-1.0, 0.0), 4); // left
        assert_eq!(direction_label(-1.0, 1.0), 5);
        assert_eq!(direction_label(0.0, 1.0), 6); // down
        assert_eq!(direction_label(1.0, 1.0), 7);
        // The wrap-around: just below and just above "right" are both right.
        assert_eq!(direction_label(1.0, 0.1), 0);
        assert_eq!(direction_label(1.0, -0.1), 0);
        assert_eq!(direction_label(0.0, 0.0), DIRECTION_NONE);
        assert_eq!(direction_label(f32::NAN, 0.0), DIRECTION_NONE);
        for d in 0..8u8 {
            let (x, y) = label_vector(d).unwrap();
            assert_eq!(direction_label(x, y), d);
        }
        assert_eq!(label_vector(DIRECTION_NONE), None);
        // Agrees with the nearest multiple of 45° of the angle, all round the circle.
        for i in 0..3600 {
            let a = (i as f32 + 0.05) * std::f32::consts::TAU / 3600.0;
            let (x, y) = (a.cos(), -a.sin());
            let expected = ((a / std::f32::consts::FRAC_PI_4).round() as i32).rem_euclid(8);
            assert_eq!(
                direction_label(x, y) as i32,
                expected,
                "{} degrees",
                a.to_degrees()
            );
        }
    }

    /// Sums of `n` motion pixels at full weight, all with gradient `(gx, gy)` and
    /// temporal difference `it`.
    fn uniform(n: i64, gx: i64, gy: i64, it: i64) -> BlockSums {
        BlockSums {
            weight: (n * GRADIENT_SATURATION as i64) as u32,
            flow_x: -n * it * gx,
            flow_y: -n * it * gy,
            gxx: n * gx * gx,
            gyy: n * gy * gy,
            gxy: n * gx * gy,
            it2: n * it * it,
        }
    }

    #[test]
    fn translation_is_recovered_with_full_coherence() {
        // Two groups of pixels with gradients (40, 0) and (0, 40), moving by
        // d = (2, −1): It = −∇I·d = −(G/4)·d.
        let mut sums = uniform(50, 40, 0, -20);
        sums += uniform(50, 0, 40, 10);
        let f = fit(&sums).unwrap();
        assert!(
            (f.vx - 2.0).abs() < 1e-9 && (f.vy + 1.0).abs() < 1e-9,
            "{f:?}"
        );
        assert!((f.coherence - 1.0).abs() < 1e-9);
        assert!((f.speed_px.unwrap() - 5f64.sqrt()).abs() < 1e-9);
        let features = Features::from_sums(&sums, 256);
        assert!((features.density - 100.0 / 256.0).abs() < 1e-6);
        let b = features.to_block(0.02);
        // (2, −1) on screen is 26.6° above the x axis: label 1 (up-right).
        assert_eq!(b.direction, 1);
        assert!((b.dx.hypot(b.dy) - features.density).abs() < 1e-6);
    }

    #[test]
    fn lucas_kanade_recovers_the_displacement_the_normal_flow_misses() {
        // A texture with one dominant orientation: T = [[9000, 3000], [3000, 2000]].
        // Moving by d = (1, −1) (up-right), the normal-flow sum T·d/4 points at −9.5°
        // (right); the Lucas–Kanade solve recovers d itself.
        let sums = BlockSums {
            weight: 50 * GRADIENT_SATURATION as u32,
            flow_x: 1500,
            flow_y: 250,
            gxx: 9000,
            gyy: 2000,
            gxy: 3000,
            it2: 1000,
        };
        let f = fit(&sums).unwrap();
        assert!(
            (f.vx - 1.0).abs() < 1e-9 && (f.vy + 1.0).abs() < 1e-9,
            "{f:?}"
        );
        assert_eq!(Features::from_sums(&sums, 256).to_block(0.02).direction, 1);
        // An edge (T of rank one): no solve, the normal flow gives the direction.
        let edge = uniform(50, 40, 0, -20);
        let f = fit(&edge).unwrap();
        assert_eq!(f.speed_px, None);
        assert!((f.coherence - 1.0).abs() < 1e-9);
        assert_eq!(Features::from_sums(&edge, 256).to_block(0.02).direction, 0);
    }

    #[test]
    fn opposite_motions_in_one_block_are_incoherent() {
        // Half the pixels move right, half left, over the same texture: nothing fits.
        let mut sums = uniform(50, 40, 0, -20);
        sums += uniform(50, 40, 0, 20);
        sums += uniform(50, 0, 40, -20);
        sums += uniform(50, 0, 40, 20);
        assert!(fit(&sums).is_none(), "b = 0: nothing explained");
        // Slightly more one way: a little coherent, no label, a short vector.
        let mut sums = uniform(60, 40, 0, -20);
        sums += uniform(40, 40, 0, 20);
        sums += uniform(100, 0, 40, 1);
        let f = fit(&sums).unwrap();
        assert!(f.coherence > 0.0 && f.coherence < 0.1, "{f:?}");
        let b = Features::from_sums(&sums, 256).to_block(0.02);
        assert_eq!(b.direction, DIRECTION_NONE);
        assert!(b.density > 0.5);
        assert!(b.dx.hypot(b.dy) < 0.1 * b.density);
    }

    #[test]
    fn weak_block_has_density_but_no_label() {
        let b = Features::from_sums(&uniform(1, 40, 0, -20), 256).to_block(0.02);
        assert!(b.density > 0.0 && b.density < 0.02);
        assert_eq!(b.direction, DIRECTION_NONE);
    }

    #[test]
    fn still_block_is_all_zero() {
        let b = Features::from_sums(&BlockSums::default(), 256).to_block(0.02);
        assert_eq!(
            b,
            BlockMotion {
                direction: DIRECTION_NONE,
                ..Default::default()
            }
        );
    }
}
