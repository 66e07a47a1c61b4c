//! The plane-to-plane homography from a camera's image to the floor.
//!
//! [`Homography::fit`] is the normalised direct linear transform (Hartley &
//! Zisserman, algorithm 4.2): both point sets are translated to their centroid and
//! scaled to a mean distance of √2, each pair gives two rows of `A h = 0`, and `h` is
//! the unit vector minimising `|A h|` — the eigenvector of `AᵀA` with the smallest
//! eigenvalue (exact for 4 pairs, least squares for more). Degenerate sets are
//! refused with the reason: duplicates, points on a line, or pairs that leave the
//! solution undetermined.
//!
//! The sign of `H` is fixed so that the calibration points have a positive
//! homogeneous `w`; image points with `w ≤ 0` lie on or beyond the horizon of the
//! floor and have no floor position ([`Homography::apply`] returns `None`).

use isochron_config::{CameraConfig, degenerate_points};

/// A point `[x, y]`.
pub type Point = [f64; 2];

/// Why a set of point pairs does not define a homography.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HomographyError {
    /// Fewer than 4 pairs.
    #[error("expected at least 4 point pairs, found {0}")]
    TooFew(usize),
    /// Image and floor lists differ in length.
    #[error("{image} image points but {floor} floor points")]
    Mismatch {
        /// Image points.
        image: usize,
        /// Floor points.
        floor: usize,
    },
    /// A non-finite coordinate.
    #[error("a coordinate is not a finite number")]
    NotFinite,
    /// One side is degenerate (duplicates, collinear points).
    #[error("the {side} points cannot define a homography: {reason}")]
    Degenerate {
        /// `image` or `floor`.
        side: &'static str,
        /// Why.
        reason: String,
    },
    /// The pairs do not pin down a single homography (or contradict any).
    #[error(
        "the point pairs do not determine a homography (rank deficient: the points are too close to a line or to each other)"
    )]
    RankDeficient,
}

/// A 3×3 homography, row-major, mapping `[x, y, 1]` to homogeneous coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Homography {
    /// The matrix.
    pub m: [[f64; 3]; 3],
}

impl Homography {
    /// Fits the homography mapping each `from[i]` to `to[i]` (at least 4 pairs).
    pub fn fit(from: &[Point], to: &[Point]) -> Result<Homography, HomographyError> {
        if from.len() != to.len() {
            return Err(HomographyError::Mismatch {
                image: from.len(),
                floor: to.len(),
            });
        }
        if from.len() < 4 {
            return Err(HomographyError::TooFew(from.len()));
        }
        if from.iter().chain(to).flatten().any(|v| !v.is_finite()) {
            return Err(HomographyError::NotFinite);
        }
        for (side, pts) in [("image", from), ("floor", to)] {
            if let Some(reason) = degenerate_points(pts) {
                return Err(HomographyError::Degenerate { side, reason });
            }
        }
        let (t_from, n_from) = normalise(from);
        let (t_to, n_to) = normalise(to);

        // AᵀA accumulated directly (9×9), two rows per pair.
        let mut ata = [[0.0f64; 9]; 9];
        for (p, q) in n_from.iter().zip(&n_to) {
            let (x, y) = (p[0], p[1]);
            let (u, v) = (q[0], q[1]);
            let rows = [
                [-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u],
                [0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v],
            ];
            for r in &rows {
                for i in 0..9 {
                    for j in 0..9 {
                        ata[i][j] += r[i] * r[j];
                    }
                }
            }
        }
        let (values, vectors) = symmetric_eigen(ata);
        let mut order: Vec<usize> = (0..9).collect();
        order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
        let (second, largest) = (values[order[1]], values[order[8]]);
        // A unique solution needs a one-dimensional null space: the second-smallest
        // eigenvalue must stand clear of zero.
        if second.is_nan() || second <= 1e-10 * largest {
            return Err(HomographyError::RankDeficient);
        }
        let h: Vec<f64> = (0..9).map(|i| vectors[i][order[0]]).collect();
        let hn = [[h[0], h[1], h[2]], [h[3], h[4], h[5]], [h[6], h[7], h[8]]];
        // Undo the normalisation: H = T_to⁻¹ · Hn · T_from.
        let m = mul(
            &mul(&inverse(&t_to).ok_or(HomographyError::RankDeficient)?, &hn),
            &t_from,
        );
        let mut hom = Homography { m };
        hom.scale_to_unit();
        // Orient so that the calibration points are in front (w > 0).
        let positive = from.iter().filter(|p| hom.w(**p) > 0.0).count();
        if positive * 2 < from.len() {
            for row in &mut hom.m {
                for v in row {
                    *v = -*v;
                }
            }
        }
        if from.iter().any(|p| hom.w(*p) <= 0.0) {
            // Calibration points on both sides of the horizon: not a view of a floor.
            return Err(HomographyError::Degenerate {
                side: "image",
                reason: "the pairs put some image points beyond the horizon of the floor".into(),
            });
        }
        Ok(hom)
    }

    /// The image → floor homography of a camera's `floor_points`, with the RMS
    /// distance (metres) of the floor points from where it maps the image points;
    /// `None` if the camera has no floor points.
    pub fn of_camera(camera: &CameraConfig) -> Result<Option<(Homography, f64)>, HomographyError> {
        if camera.floor_points.is_empty() {
            return Ok(None);
        }
        let image: Vec<Point> = camera.floor_points.iter().map(|p| p.image_px).collect();
        let floor: Vec<Point> = camera.floor_points.iter().map(|p| p.floor_m).collect();
        let h = Homography::fit(&image, &floor)?;
        let rms = h.rms_error(&image, &floor);
        Ok(Some((h, rms)))
    }

    fn scale_to_unit(&mut self) {
        let norm = self.m.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
        if norm > 0.0 {
            for row in &mut self.m {
                for v in row {
                    *v /= norm;
                }
            }
        }
    }

    /// The homogeneous `w` of `p` (its sign tells the side of the horizon).
    pub fn w(&self, p: Point) -> f64 {
        self.m[2][0] * p[0] + self.m[2][1] * p[1] + self.m[2][2]
    }

    /// Maps `p`; `None` on or beyond the horizon (`w` not clearly positive).
    pub fn apply(&self, p: Point) -> Option<Point> {
        let w = self.w(p);
        let scale = self.m[2][2]
            .abs()
            .max(self.m[2][0].abs())
            .max(self.m[2][1].abs());
        if w.is_nan() || w <= 1e-12 * scale.max(1e-300) {
            return None;
        }
        let x = (self.m[0][0] * p[0] + self.m[0][1] * p[1] + self.m[0][2]) / w;
        let y = (self.m[1][0] * p[0] + self.m[1][1] * p[1] + self.m[1][2]) / w;
        (x.is_finite() && y.is_finite()).then_some([x, y])
    }

    /// The inverse mapping (floor → image), if the matrix is invertible.
    pub fn inverse(&self) -> Option<Homography> {
        let mut inv = Homography {
            m: inverse(&self.m)?,
        };
        inv.scale_to_unit();
        Some(inv)
    }

    /// Root mean square distance between `H(from[i])` and `to[i]` (infinite if a
    /// point does not map).
    pub fn rms_error(&self, from: &[Point], to: &[Point]) -> f64 {
        let mut sum = 0.0;
        for (p, q) in from.iter().zip(to) {
            match self.apply(*p) {
                Some(r) => sum += (r[0] - q[0]).powi(2) + (r[1] - q[1]).powi(2),
                None => return f64::INFINITY,
            }
        }
        (sum / from.len().max(1) as f64).sqrt()
    }
}

/// Hartley normalisation: the similarity taking `pts` to centroid 0 and mean
/// distance √2, and the transformed points.
fn normalise(pts: &[Point]) -> ([[f64; 3]; 3], Vec<Point>) {
    let n = pts.len() as f64;
    let cx = pts.iter().map(|p| p[0]).sum::<f64>() / n;
    let cy = pts.iter().map(|p| p[1]).sum::<f64>() / n;
    let mean = pts
        .iter()
        .map(|p| (p[0] - cx).hypot(p[1] - cy))
        .sum::<f64>()
        / n;
    let s = if mean > 0.0 {
        std::f64::consts::SQRT_2 / mean
    } else {
        1.0
    };
    let t = [[s, 0.0, -s * cx], [0.0, s, -s * cy], [0.0, 0.0, 1.0]];
    let out = pts
        .iter()
        .map(|p| [s * (p[0] - cx), s * (p[1] - cy)])
        .collect();
    (t, out)
}

fn mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn inverse(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let c =
        |r0: usize, r1: usize, c0: usize, c1: usize| m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0];
    let cof = [
        [c(1, 2, 1, 2), -c(1, 2, 0, 2), c(1, 2, 0, 1)],
        [-c(0, 2, 1, 2), c(0, 2, 0, 2), -c(0, 2, 0, 1)],
        [c(0, 1, 1, 2), -c(0, 1, 0, 2), c(0, 1, 0, 1)],
    ];
    let det = m[0][0] * cof[0][0] + m[0][1] * cof[0][1] + m[0][2] * cof[0][2];
    let norm = m.iter().flatten().map(|v| v.abs()).fold(0.0, f64::max);
    if !det.is_finite() || det.abs() <= 1e-14 * norm.powi(3) {
        return None;
    }
    // inverse = adjugate / det; the adjugate is the transposed cofactor matrix.
    let mut inv = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            inv[i][j] = cof[j][i] / det;
        }
    }
    Some(inv)
}

/// Eigen-decomposition of a symmetric 9×9 matrix by cyclic Jacobi rotations:
/// returns the eigenvalues and the eigenvectors as columns.
fn symmetric_eigen(mut a: [[f64; 9]; 9]) -> ([f64; 9], [[f64; 9]; 9]) {
    let mut v = [[0.0f64; 9]; 9];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..100 {
        let off: f64 = (0..9)
            .flat_map(|i| (0..9).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        let total: f64 = a.iter().flatten().map(|x| x * x).sum();
        if off <= 1e-30 * total.max(1e-300) {
            break;
        }
        for p in 0..8 {
            for q in p + 1..9 {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                // A ← A·J (columns p, q), then A ← Jᵀ·A (rows p, q).
                for row in a.iter_mut() {
                    let (akp, akq) = (row[p], row[q]);
                    row[p] = c * akp - s * akq;
                    row[q] = s * akp + c * akq;
                }
                let (row_p, row_q) = (a[p], a[q]);
                for (k, (apk, aqk)) in row_p.iter().zip(&row_q).enumerate() {
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    let mut values = [0.0; 9];
    for (i, value) in values.iter_mut().enumerate() {
        *value = a[i][i];
    }
    (values, v)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A perspective view: floor = H_true(image).
    fn h_true() -> Homography {
        Homography {
            m: [
                [0.02, 0.004, -3.0],
                [0.001, -0.03, 9.0],
                [0.0001, 0.0012, 1.0],
            ],
        }
    }

    fn pairs(image: &[Point]) -> Vec<Point> {
        image.iter().map(|p| h_true().apply(*p).unwrap()).collect()
    }

    #[test]
    fn four_pairs_round_trip_exactly() {
        let image = [[10.0, 400.0], [600.0, 420.0], [500.0, 120.0], [80.0, 100.0]];
        let floor = pairs(&image);
        let h = Homography::fit(&image, &floor).unwrap();
        for (p, q) in image.iter().zip(&floor) {
            let r = h.apply(*p).unwrap();
            assert!(
                (r[0] - q[0]).abs() < 1e-9 && (r[1] - q[1]).abs() < 1e-9,
                "{r:?} vs {q:?}"
            );
        }
        // Points that were not used map like the true homography does.
        for p in [[320.0, 240.0], [1.0, 1.0], [639.0, 479.0]] {
            let (a, b) = (h.apply(p).unwrap(), h_true().apply(p).unwrap());
            assert!((a[0] - b[0]).abs() < 1e-8 && (a[1] - b[1]).abs() < 1e-8);
        }
        // And back.
        let inv = h.inverse().unwrap();
        let back = inv.apply(h.apply([123.0, 321.0]).unwrap()).unwrap();
        assert!((back[0] - 123.0).abs() < 1e-7 && (back[1] - 321.0).abs() < 1e-7);
        assert!(h.rms_error(&image, &floor) < 1e-9);
    }

    #[test]
    fn more_pairs_are_a_least_squares_fit() {
        let image: Vec<Point> = (0..5)
            .flat_map(|i| (0..4).map(move |j| [40.0 + 140.0 * i as f64, 60.0 + 120.0 * j as f64]))
            .collect();
        let exact = pairs(&image);
        // Perturb each floor point by ±1 cm in a fixed pattern.
        let noisy: Vec<Point> = exact
            .iter()
            .enumerate()
            .map(|(k, q)| {
                let e = if k % 2 == 0 { 0.01 } else { -0.01 };
                [q[0] + e, q[1] - e]
            })
            .collect();
        let h = Homography::fit(&image, &noisy).unwrap();
        let rms = h.rms_error(&image, &noisy);
        assert!(rms > 0.0 && rms < 0.015, "rms {rms}");
        // The fit averages the noise: closer to the truth than the noise.
        let truth_rms = h.rms_error(&image, &exact);
        assert!(truth_rms < 0.01, "{truth_rms}");
    }

    #[test]
    fn degenerate_sets_are_refused() {
        let good = [[0.0, 0.0], [100.0, 0.0], [100.0, 100.0], [0.0, 100.0]];
        let floor = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        assert!(Homography::fit(&good, &floor).is_ok());
        // Too few.
        assert_eq!(
            Homography::fit(&good[..3], &floor[..3]),
            Err(HomographyError::TooFew(3))
        );
        // A duplicate image point.
        let dup = [[0.0, 0.0], [100.0, 0.0], [100.0, 0.0], [0.0, 100.0]];
        let err = Homography::fit(&dup, &floor).unwrap_err();
        assert!(err.to_string().contains("are the same"), "{err}");
        // Three of four image points on a line.
        let line3 = [[0.0, 0.0], [50.0, 0.0], [100.0, 0.0], [0.0, 100.0]];
        let err = Homography::fit(&line3, &floor).unwrap_err();
        assert!(err.to_string().contains("on one line"), "{err}");
        // All of many floor points on a line.
        let image: Vec<Point> = (0..6).map(|i| [i as f64 * 10.0, (i * i) as f64]).collect();
        let flat: Vec<Point> = (0..6).map(|i| [i as f64, 2.0 * i as f64]).collect();
        let err = Homography::fit(&image, &flat).unwrap_err();
        assert!(
            matches!(&err, HomographyError::Degenerate { side: "floor", .. }),
            "{err}"
        );
        // Not finite.
        let nan = [[0.0, 0.0], [f64::NAN, 0.0], [100.0, 100.0], [0.0, 100.0]];
        assert_eq!(
            Homography::fit(&nan, &floor),
            Err(HomographyError::NotFinite)
        );
        // Five points, four of them on a line: not all collinear, but the pairs leave
        // a two-dimensional family of solutions (7 constraints for 8 unknowns).
        let five = [
            [0.0, 0.0],
            [10.0, 0.0],
            [20.0, 0.0],
            [30.0, 0.0],
            [5.0, 50.0],
        ];
        let five_floor: Vec<Point> = five.iter().map(|p| [p[0] / 10.0, p[1] / 10.0]).collect();
        assert!(matches!(
            Homography::fit(&five, &five_floor),
            Err(HomographyError::RankDeficient)
        ));
    }

    #[test]
    fn beyond_the_horizon_has_no_floor_point() {
        let h = h_true();
        // w = 0.0001 x + 0.0012 y + 1: negative for y < -833 at x = 0.
        assert!(h.apply([0.0, -900.0]).is_none());
        assert!(h.apply([0.0, 0.0]).is_some());
    }

    /// The demo's floor points (config/demo.toml) agree with the camera's Tsai
    /// calibration at points they were not made from: people's feet in the PETS
    /// ground truth, projected into the image by the calibration.
    #[test]
    fn the_demo_floor_mapping_matches_the_calibration() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/demo.toml");
        let loaded = isochron_config::Config::load(&path).unwrap();
        let cam = &loaded.config.cameras[0];
        let (h, rms) = Homography::of_camera(cam).unwrap().unwrap();
        assert!(rms < 0.25, "rms {rms} m at the calibration points");
        // (image px from the Tsai model) ↔ (ground truth, metres).
        let checks = [
            ([513.0, 232.0], [-4.1554, -7.3591]),
            ([493.0, 222.0], [-3.4648, -6.4751]),
            ([664.0, 370.0], [-11.259, -13.578]),
            ([217.0, 238.0], [-7.5238, -1.0053]),
            ([631.0, 352.0], [-10.694, -12.793]),
            ([419.0, 249.0], [-6.4057, -6.0808]),
            ([412.0, 265.0], [-7.6167, -6.6136]),
            ([537.0, 334.0], [-10.548, -10.962]),
        ];
        for (image, floor) in checks {
            let p = h.apply(image).unwrap();
            let err = (p[0] - floor[0]).hypot(p[1] - floor[1]);
            assert!(
                err < 0.3,
                "{image:?} maps to {p:?}, the calibration says {floor:?} ({err:.3} m)"
            );
        }
    }

    #[test]
    fn eigen_decomposition_is_exact_on_a_known_matrix() {
        let mut a = [[0.0; 9]; 9];
        for (i, row) in a.iter_mut().enumerate() {
            row[i] = (i + 1) as f64;
        }
        a[0][1] = 0.5;
        a[1][0] = 0.5;
        let (values, vectors) = symmetric_eigen(a);
        for k in 0..9 {
            // A v = λ v
            for i in 0..9 {
                let av: f64 = (0..9).map(|j| a[i][j] * vectors[j][k]).sum();
                assert!((av - values[k] * vectors[i][k]).abs() < 1e-10);
            }
        }
    }
}
