use super::*;
use isochron_wire::FLAG_ILLUMINATION;

/// A smooth random texture, isotropic at block scale: a sum of 8 sinusoids
/// (wavelengths 12–28 px) with random orientations and phases, values in
/// 20..=230. (A texture with a single orientation per block would leave only the
/// normal flow knowable — the aperture problem — which is not what this tests.)
struct Texture {
    waves: Vec<(f64, f64, f64)>,
}

impl Texture {
    fn new(seed: u64) -> Self {
        let mut x = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        let waves = (0..8)
            .map(|i| {
                // Spread the orientations over the half circle, jittered.
                let angle = (i as f64 + next()) * std::f64::consts::PI / 8.0;
                let k = std::f64::consts::TAU / (12.0 + 16.0 * next());
                (
                    k * angle.cos(),
                    k * angle.sin(),
                    next() * std::f64::consts::TAU,
                )
            })
            .collect();
        Texture { waves }
    }

    fn at(&self, x: f64, y: f64) -> u8 {
        let v: f64 = self
            .waves
            .iter()
            .map(|(kx, ky, p)| (kx * x + ky * y + p).sin())
            .sum();
        (125.0 + 30.0 * v).clamp(20.0, 230.0) as u8
    }
}

/// A frame of `w × h`: the background texture, with a square of `side` px at
/// (`sx`, `sy`) carrying its own texture (attached to the square).
fn scene(w: usize, h: usize, bg: &Texture, square: Option<(&Texture, f64, f64, f64)>) -> Vec<u8> {
    let mut f = vec![0u8; w * h];
    for y in 0..h {
        for x in 0..w {
            let (xf, yf) = (x as f64, y as f64);
            f[y * w + x] = match square {
                Some((t, sx, sy, side))
                    if xf >= sx && xf < sx + side && yf >= sy && yf < sy + side =>
                {
                    t.at(xf - sx, yf - sy).saturating_add(20)
                }
                _ => bg.at(xf, yf) / 2,
            };
        }
    }
    f
}

/// A detector per kernel, motion only (the appearance has its own test).
fn detector(w: usize, h: usize, mask: &[Polygon]) -> Vec<MotionDetector> {
    let geom = Geometry::new(w, h, 16).unwrap();
    let params = MotionParams {
        appearance_hz: 0.0,
        ..MotionParams::default()
    };
    Implementation::available()
        .into_iter()
        .map(|imp| MotionDetector::with_implementation(geom, params, imp, mask))
        .collect()
}

#[test]
fn the_appearance_is_measured_when_due_and_flagged() {
    let (w, h) = (64, 32);
    let geom = Geometry::new(w, h, 16).unwrap();
    let params = MotionParams {
        appearance_hz: 2.0,
        ..MotionParams::default()
    };
    let mut d = MotionDetector::with_implementation(
        geom,
        params,
        Implementation::Portable,
        &[vec![[0.0, 0.0], [16.0, 0.0], [16.0, 16.0], [0.0, 16.0]]],
    );
    let frame = vec![90u8; w * h];
    let mut out = vec![BlockMotion::default(); geom.blocks()];
    // 2 Hz: the first frame of each half second of capture time.
    let flags: Vec<u32> = [0, 100, 400, 500, 600]
        .iter()
        .map(|ms| {
            let report = d.process(&frame, &frame, ms * 1_000_000, &mut out).unwrap();
            assert_eq!(report.appearance, report.flags & FLAG_APPEARANCE != 0);
            if report.appearance {
                // The masked block is zero, the others their grey level.
                assert_eq!(out[0].luma, 0);
                assert!(
                    out[1..]
                        .iter()
                        .all(|b| b.luma == 90 * 256 && b.texture == 0)
                );
            } else {
                assert!(out.iter().all(|b| b.luma == 0));
            }
            report.flags
        })
        .collect();
    assert_eq!(flags, [FLAG_APPEARANCE, 0, 0, FLAG_APPEARANCE, 0]);
}

fn run(d: &mut MotionDetector, prev: &[u8], cur: &[u8]) -> (FrameReport, Vec<BlockMotion>) {
    let mut out = vec![BlockMotion::default(); d.geometry().blocks()];
    let report = d.process(prev, cur, 0, &mut out).unwrap();
    (report, out)
}

/// Blocks wholly inside the square in both frames; blocks not within 2 px of it
/// in either frame.
fn classify(geom: &Geometry, a: (f64, f64), b: (f64, f64), side: f64) -> (Vec<usize>, Vec<usize>) {
    let (mut inside, mut outside) = (Vec::new(), Vec::new());
    for blk in 0..geom.blocks() {
        let (x0, y0, bw, bh) = geom.block_rect(blk);
        let (x0, y0, x1, y1) = (x0 as f64, y0 as f64, (x0 + bw) as f64, (y0 + bh) as f64);
        let within =
            |(sx, sy): (f64, f64)| x0 >= sx && y0 >= sy && x1 <= sx + side && y1 <= sy + side;
        let near = |(sx, sy): (f64, f64)| {
            x1 > sx - 2.0 && x0 < sx + side + 2.0 && y1 > sy - 2.0 && y0 < sy + side + 2.0
        };
        if within(a) && within(b) {
            inside.push(blk);
        } else if !near(a) && !near(b) {
            outside.push(blk);
        }
    }
    (inside, outside)
}

#[test]
fn textured_square_moving_in_each_direction_gives_that_direction() {
    let (w, h, side) = (160, 128, 64.0);
    let bg = Texture::new(1);
    let fg = Texture::new(2);
    for mut d in detector(w, h, &[]) {
        for dir in 0..8u8 {
            for speed in [2.0, 3.0, 4.0] {
                let (ux, uy) = crate::features::label_vector(dir).unwrap();
                let (ux, uy) = (ux.round() as f64, uy.round() as f64);
                let a = (48.0, 32.0);
                let b = (a.0 + ux * speed, a.1 + uy * speed);
                let prev = scene(w, h, &bg, Some((&fg, a.0, a.1, side)));
                let cur = scene(w, h, &bg, Some((&fg, b.0, b.1, side)));
                let (report, blocks) = run(&mut d, &prev, &cur);
                let (inside, outside) = classify(d.geometry(), a, b, side);
                assert!(inside.len() >= 4, "{inside:?}");
                let name = d.backend_name();
                let mut exact = 0;
                for &blk in &inside {
                    let m = blocks[blk];
                    assert!(m.density >= d.params().density_threshold, "{name}: {m:?}");
                    // Blocks with few motion pixels may see only one edge of the
                    // texture; then their label is the edge's normal, within 45°.
                    let near = [dir, (dir + 1) % 8, (dir + 7) % 8];
                    assert!(
                        m.direction == dir || (m.density < 0.1 && near.contains(&m.direction)),
                        "{name}: direction {dir} speed {speed}: block {blk} {m:?}"
                    );
                    exact += (m.direction == dir) as usize;
                }
                assert!(
                    exact * 10 >= inside.len() * 9,
                    "{name}: {exact} of {}",
                    inside.len()
                );
                for &blk in &outside {
                    assert_eq!(blocks[blk].density, 0.0, "{name}: block {blk} moved");
                    assert_eq!(blocks[blk].direction, DIRECTION_NONE);
                }
                assert!(!report.suppressed);
                assert_eq!(report.flags, 0);
            }
        }
    }
}

#[test]
fn global_brightness_step_is_compensated_and_flagged() {
    let (w, h) = (160, 128);
    let bg = Texture::new(3);
    let fg = Texture::new(4);
    for mut d in detector(w, h, &[]) {
        let prev = scene(w, h, &bg, None);
        let cur: Vec<u8> = prev.iter().map(|&v| v + 40).collect();
        let (report, blocks) = run(&mut d, &prev, &cur);
        assert_eq!(report.offset, 40);
        assert_eq!(report.flags, FLAG_ILLUMINATION);
        assert!(
            blocks.iter().all(|b| b.density == 0.0),
            "{}",
            d.backend_name()
        );

        // A person moving during the step is still seen, and only there.
        let prev = scene(w, h, &bg, Some((&fg, 48.0, 32.0, 48.0)));
        let cur: Vec<u8> = scene(w, h, &bg, Some((&fg, 51.0, 32.0, 48.0)))
            .iter()
            .map(|&v| v.saturating_add(40))
            .collect();
        let (report, blocks) = run(&mut d, &prev, &cur);
        assert_eq!(report.flags, FLAG_ILLUMINATION);
        assert!(!report.suppressed);
        let (inside, outside) = classify(d.geometry(), (48.0, 32.0), (51.0, 32.0), 48.0);
        assert!(inside.iter().all(|&b| blocks[b].direction == 0));
        assert!(outside.iter().all(|&b| blocks[b].density == 0.0));
    }
}

#[test]
fn gain_change_is_detected_and_suppressed() {
    // Auto-exposure: everything 50 % brighter. The offset removes the mean;
    // what is left changes most blocks in no common direction.
    let (w, h) = (160, 128);
    let bg = Texture::new(5);
    for mut d in detector(w, h, &[]) {
        let prev = scene(w, h, &bg, None);
        let cur: Vec<u8> = prev.iter().map(|&v| (v as f32 * 1.5) as u8).collect();
        let (report, blocks) = run(&mut d, &prev, &cur);
        assert!(report.changed_fraction >= 0.5, "{report:?}");
        assert!(report.suppressed, "{report:?}");
        assert_eq!(report.flags, FLAG_ILLUMINATION);
        assert_eq!(report.moving_blocks, 0);
        assert!(
            blocks
                .iter()
                .all(|b| b.density == 0.0 && b.direction == DIRECTION_NONE)
        );
    }
}

#[test]
fn coherent_whole_view_motion_is_not_an_illumination_change() {
    // The camera shakes 2 px to the right: every block moves, all the same way.
    let (w, h) = (160, 128);
    let bg = Texture::new(6);
    for mut d in detector(w, h, &[]) {
        let frame = |dx: f64| -> Vec<u8> {
            (0..w * h)
                .map(|i| bg.at((i % w) as f64 - dx, (i / w) as f64))
                .collect()
        };
        let (report, blocks) = run(&mut d, &frame(0.0), &frame(2.0));
        assert!(report.changed_fraction > 0.8, "{report:?}");
        assert!(!report.suppressed, "{report:?}");
        let right = blocks.iter().filter(|b| b.direction == 0).count();
        assert!(
            right * 10 >= blocks.len() * 9,
            "{right} of {}",
            blocks.len()
        );
        // The rest are edges (aperture: only the normal flow) — never opposite.
        assert!(
            blocks
                .iter()
                .all(|b| matches!(b.direction, 7 | 0 | 1 | DIRECTION_NONE))
        );
    }
}

#[test]
fn masked_region_never_reports_motion() {
    let (w, h) = (160, 128);
    let bg = Texture::new(7);
    let fg = Texture::new(8);
    // Mask the left half; a square moves across the middle.
    let mask = vec![vec![[0.0, 0.0], [80.0, 0.0], [80.0, 128.0], [0.0, 128.0]]];
    for mut d in detector(w, h, &mask) {
        assert_eq!(d.masked_blocks(), 5 * 8);
        let prev = scene(w, h, &bg, Some((&fg, 40.0, 40.0, 80.0)));
        let cur = scene(w, h, &bg, Some((&fg, 43.0, 40.0, 80.0)));
        let (report, blocks) = run(&mut d, &prev, &cur);
        for (b, blk) in blocks.iter().enumerate() {
            let masked = b % 10 < 5;
            if masked {
                assert_eq!(
                    *blk,
                    BlockMotion {
                        direction: DIRECTION_NONE,
                        ..Default::default()
                    }
                );
            }
        }
        // The unmasked half of the square moves.
        assert!(
            blocks
                .iter()
                .enumerate()
                .any(|(b, m)| b % 10 >= 5 && m.direction == 0)
        );
        assert!(report.moving_blocks > 0);
    }
}

#[test]
fn shimmering_static_edge_is_not_motion_but_a_moving_one_is() {
    // A high-contrast vertical edge (40 → 240 over ~3 px). Shifted by 0.3 px it
    // changes pixels by up to ~25 grey levels: above the difference threshold,
    // but its normal flow is below min_flow_px. Shifted by 2 px it moves.
    let (w, h) = (64, 32);
    let edge = |shift: f64| -> Vec<u8> {
        (0..w * h)
            .map(|i| {
                let x = (i % w) as f64 - 32.0 - shift;
                (140.0 + 100.0 * (x / 1.5).tanh()).round() as u8
            })
            .collect()
    };
    let geom = Geometry::new(w, h, 16).unwrap();
    let with = MotionParams::default();
    let without = MotionParams {
        thresholds: Thresholds {
            speed: 0,
            ..with.thresholds
        },
        ..with
    };
    for imp in Implementation::available() {
        let mut d = MotionDetector::with_implementation(geom, with, imp, &[]);
        let mut plain = MotionDetector::with_implementation(geom, without, imp, &[]);
        let (_, shimmer) = run(&mut d, &edge(0.0), &edge(0.3));
        let (_, shimmer_plain) = run(&mut plain, &edge(0.0), &edge(0.3));
        assert!(
            shimmer.iter().all(|b| b.density == 0.0),
            "{}: {shimmer:?}",
            d.backend_name()
        );
        assert!(
            shimmer_plain.iter().any(|b| b.density > 0.0),
            "the test needs |It| ≥ diff"
        );
        let (_, moved) = run(&mut d, &edge(0.0), &edge(2.0));
        assert!(
            moved.iter().any(|b| b.density >= 0.02 && b.direction == 0),
            "{moved:?}"
        );
    }
}

#[test]
fn wrong_sizes_are_errors_not_panics() {
    let mut d = detector(32, 32, &[]).remove(0);
    let f = vec![0u8; 32 * 32];
    let mut out = vec![BlockMotion::default(); 4];
    assert!(d.process(&f, &f[..100], 0, &mut out).is_err());
    let mut short = vec![BlockMotion::default(); 3];
    assert!(d.process(&f, &f, 0, &mut short).is_err());
    assert!(d.process(&f, &f, 0, &mut out).is_ok());
}

#[test]
fn dis_backend_sees_the_moving_square() {
    let (w, h, side) = (160, 128, 64.0);
    let bg = Texture::new(9);
    let fg = Texture::new(10);
    let config = MotionConfig {
        backend: MotionBackend::Dis,
        ..MotionConfig::default()
    };
    let mut d = MotionDetector::new(&config, w, h, &[]).unwrap();
    assert_eq!(d.backend_name(), "dis");
    let a = (48.0, 32.0);
    let b = (51.0, 32.0);
    let prev = scene(w, h, &bg, Some((&fg, a.0, a.1, side)));
    let cur = scene(w, h, &bg, Some((&fg, b.0, b.1, side)));
    let (_, blocks) = run(&mut d, &prev, &cur);
    let (inside, outside) = classify(d.geometry(), a, b, side);
    let right = inside.iter().filter(|&&b| blocks[b].direction == 0).count();
    assert!(right * 4 >= inside.len() * 3, "{right} of {}", inside.len());
    let quiet = outside
        .iter()
        .filter(|&&b| blocks[b].density < 0.02)
        .count();
    assert!(
        quiet * 10 >= outside.len() * 9,
        "{quiet} of {}",
        outside.len()
    );
}
