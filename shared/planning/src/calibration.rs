//! How well a camera's `floor_points` agree with the homography fitted to them:
//! per-point residuals (metres on the floor, pixels in the image), the
//! leave-one-out error of each point (the fit without it, evaluated at it), and
//! which point stands out — one wrong tape mark skews the whole footprint, and it
//! shows as a leave-one-out error far above the others.

use serde::Serialize;

use crate::homography::{Homography, HomographyError, Point};

/// A point is flagged when its leave-one-out image error is this many times the
/// median leave-one-out image error of the points...
pub const OUTLIER_FACTOR: f64 = 4.0;
/// ... and above this many pixels (below it, every point is good enough). The test
/// is in pixels, not metres: a pixel far off spans more floor than one close by,
/// so metres would flag the far points of every good calibration.
pub const OUTLIER_MIN_PX: f64 = 4.0;

/// One calibration point and how far the fit misses it.
#[derive(Debug, Clone, Serialize)]
pub struct PointResidual {
    /// Position in `floor_points` (0-based).
    pub index: usize,
    /// The configured image point, pixels.
    pub image_px: Point,
    /// The configured floor point, metres.
    pub floor_m: Point,
    /// Where the fit maps the image point on the floor (`None`: beyond the horizon).
    pub mapped_floor_m: Option<Point>,
    /// Where the fit maps the floor point in the image (`None`: behind the camera).
    pub mapped_image_px: Option<Point>,
    /// Distance on the floor between the floor point and the mapped image point, m.
    pub residual_m: f64,
    /// Distance in the image between the image point and the mapped floor point, px.
    pub residual_px: f64,
    /// Floor error at this point of the fit to all other points, m (`None` when the
    /// others do not determine a homography).
    pub loo_m: Option<f64>,
    /// Image error at this point of the fit to all other points, px.
    pub loo_px: Option<f64>,
    /// True if the point stands out (see [`OUTLIER_FACTOR`], [`OUTLIER_MIN_PX`]).
    pub flagged: bool,
}

/// The residuals of a camera's calibration.
#[derive(Debug, Clone, Serialize)]
pub struct Calibration {
    /// The fit to all points, row-major image → floor.
    #[serde(skip)]
    pub homography: Homography,
    /// RMS floor residual, metres.
    pub rms_m: f64,
    /// RMS image residual, pixels.
    pub rms_px: f64,
    /// RMS leave-one-out floor error, metres (`None` with fewer than 5 points).
    pub loo_rms_m: Option<f64>,
    /// RMS leave-one-out image error, pixels (`None` with fewer than 5 points).
    pub loo_rms_px: Option<f64>,
    /// Each point.
    pub points: Vec<PointResidual>,
}

impl Calibration {
    /// Fits `image[i] → floor[i]` and measures every point.
    pub fn analyse(image: &[Point], floor: &[Point]) -> Result<Calibration, HomographyError> {
        let h = Homography::fit(image, floor)?;
        let inv = h.inverse().ok_or(HomographyError::RankDeficient)?;
        let dist = |a: Point, b: Point| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
        let mut points: Vec<PointResidual> = image
            .iter()
            .zip(floor)
            .enumerate()
            .map(|(index, (&p, &q))| {
                let mapped_floor_m = h.apply(p);
                let mapped_image_px = inv.apply(q);
                // Leave one out: four others are the minimum, but they fit exactly
                // and say nothing; report it anyway when the fit exists.
                let loo = (image.len() > 4)
                    .then(|| {
                        let others = |v: &[Point]| -> Vec<Point> {
                            v.iter()
                                .enumerate()
                                .filter(|(j, _)| *j != index)
                                .map(|(_, x)| *x)
                                .collect()
                        };
                        let fit = Homography::fit(&others(image), &others(floor)).ok()?;
                        let m = fit.apply(p).map_or(f64::INFINITY, |r| dist(r, q));
                        let px = fit
                            .inverse()
                            .and_then(|i| i.apply(q))
                            .map_or(f64::INFINITY, |r| dist(r, p));
                        Some((m, px))
                    })
                    .flatten();
                PointResidual {
                    index,
                    image_px: p,
                    floor_m: q,
                    mapped_floor_m,
                    mapped_image_px,
                    residual_m: mapped_floor_m.map_or(f64::INFINITY, |r| dist(r, q)),
                    residual_px: mapped_image_px.map_or(f64::INFINITY, |r| dist(r, p)),
                    loo_m: loo.map(|l| l.0),
                    loo_px: loo.map(|l| l.1),
                    flagged: false,
                }
            })
            .collect();
        let rms = |v: &mut dyn Iterator<Item = f64>| {
            let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
            (s / n.max(1) as f64).sqrt()
        };
        let all = points.iter().all(|p| p.loo_m.is_some());
        let loo_rms_m = all.then(|| rms(&mut points.iter().filter_map(|p| p.loo_m)));
        let loo_rms_px = all.then(|| rms(&mut points.iter().filter_map(|p| p.loo_px)));
        let loo_px: Vec<f64> = points.iter().filter_map(|p| p.loo_px).collect();
        if let Some(median) = median(&loo_px) {
            for p in &mut points {
                if let Some(l) = p.loo_px {
                    p.flagged = l > OUTLIER_MIN_PX && l > OUTLIER_FACTOR * median;
                }
            }
        }
        Ok(Calibration {
            homography: h,
            rms_m: rms(&mut points.iter().map(|p| p.residual_m)),
            rms_px: rms(&mut points.iter().map(|p| p.residual_px)),
            loo_rms_m,
            loo_rms_px,
            points,
        })
    }
}

fn median(values: &[f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A perspective view of a floor: a 4×3 grid of image points.
    fn view() -> (Vec<Point>, Vec<Point>) {
        let h = Homography {
            m: [
                [0.02, 0.001, -3.0],
                [0.0005, -0.03, 12.0],
                [0.0, 0.0015, 1.0],
            ],
        };
        let image: Vec<Point> = [100.0, 300.0, 500.0, 700.0]
            .iter()
            .flat_map(|&x| [200.0, 350.0, 500.0].map(move |y| [x, y]))
            .collect();
        let floor = image.iter().map(|p| h.apply(*p).unwrap()).collect();
        (image, floor)
    }

    #[test]
    fn exact_points_have_no_residual_and_no_flag() {
        let (image, floor) = view();
        let c = Calibration::analyse(&image, &floor).unwrap();
        assert!(
            c.rms_m < 1e-9 && c.rms_px < 1e-6,
            "{} {}",
            c.rms_m,
            c.rms_px
        );
        assert!(c.loo_rms_m.unwrap() < 1e-6);
        assert!(c.points.iter().all(|p| !p.flagged));
    }

    #[test]
    fn one_wrong_tape_mark_is_flagged() {
        let (image, mut floor) = view();
        // Small noise everywhere, and point 7 measured 1.5 m off.
        for (i, q) in floor.iter_mut().enumerate() {
            q[0] += 0.03 * ((i * 7 % 5) as f64 - 2.0) / 2.0;
        }
        floor[7][1] += 1.5;
        let c = Calibration::analyse(&image, &floor).unwrap();
        let flagged: Vec<usize> = c
            .points
            .iter()
            .filter(|p| p.flagged)
            .map(|p| p.index)
            .collect();
        assert_eq!(flagged, vec![7], "{:#?}", c.points);
        assert!(c.points[7].loo_m.unwrap() > 1.0);
        // The residuals at the points are consistent with the RMS.
        let rms = (c.points.iter().map(|p| p.residual_m.powi(2)).sum::<f64>()
            / c.points.len() as f64)
            .sqrt();
        assert!((rms - c.rms_m).abs() < 1e-12);
        assert!(c.points.iter().all(|p| p.residual_px.is_finite()));
    }

    #[test]
    fn the_demo_calibration_has_its_known_error_and_no_outlier() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/demo.toml");
        let loaded = isochron_config::Config::load(&path).unwrap();
        let cam = &loaded.config.cameras[0];
        let image: Vec<Point> = cam.floor_points.iter().map(|p| p.image_px).collect();
        let floor: Vec<Point> = cam.floor_points.iter().map(|p| p.floor_m).collect();
        let c = Calibration::analyse(&image, &floor).unwrap();
        let (_, rms) = Homography::of_camera(cam).unwrap().unwrap();
        assert!((c.rms_m - rms).abs() < 1e-12);
        // The lens distortion a homography cannot model: about 0.1 m.
        assert!((0.03..0.2).contains(&c.rms_m), "{}", c.rms_m);
        assert!(c.points.iter().all(|p| !p.flagged), "{:#?}", c.points);
        eprintln!(
            "demo: rms {:.3} m {:.2} px, loo {:.3} m",
            c.rms_m,
            c.rms_px,
            c.loo_rms_m.unwrap()
        );
    }

    #[test]
    fn four_points_have_no_leave_one_out() {
        let (image, floor) = view();
        let pick = |v: &[Point]| [0, 2, 9, 11].map(|i| v[i]);
        let c = Calibration::analyse(&pick(&image), &pick(&floor)).unwrap();
        assert!(c.loo_rms_m.is_none());
        assert!(c.points.iter().all(|p| p.loo_m.is_none() && !p.flagged));
    }
}
