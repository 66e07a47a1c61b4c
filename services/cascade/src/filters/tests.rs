use super::*;
use fastrand::Rng as Lcg;

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

#[test]
fn alpha_is_pinned_for_the_three_filters() {
    // The corrected table of docs/ARCHITECTURE.md, section 'Filters' (the paper
    // swaps the first two).
    let l1 = alpha(30.0 * 60.0, 30.0);
    assert!(close(l1, 0.999957, 5e-7), "F_L1 α = {l1}");
    let l2 = alpha(10.0, 1.0);
    assert!(close(l2, 0.794, 5e-4), "F_L2 α = {l2}");
    let s1 = alpha(20.0, 1.0);
    assert!(close(s1, 0.891, 5e-4), "F_S1 α = {s1}");
    // The definition: n = r·T samples of zero input decay to exactly 10 %.
    assert!(close(l1.powf(30.0 * 1800.0), 0.1, 1e-9));
    assert_eq!(alpha(0.0, 30.0), 0.0);
    assert_eq!(alpha(10.0, f64::NAN), 0.0);
}

#[test]
fn warmup_weight_averages_then_becomes_the_ema() {
    assert_eq!(warmup_weight(0.1, 0), 1.0);
    assert_eq!(warmup_weight(0.1, 1), 0.5);
    assert_eq!(warmup_weight(0.1, 3), 0.25);
    assert_eq!(warmup_weight(0.1, 9), 0.1);
    assert_eq!(warmup_weight(0.1, 1000), 0.1);
}

/// Step response of an EMA with weight 1−α: y(n) = 1 − α^n for a unit step from 0.
#[test]
fn f_l1_baseline_step_response_is_the_analytic_ema() {
    let a = alpha(2.0, 10.0) as f32; // T = 2 s at 10 fps: 20 samples to 10 %
    let mut b = 0.0f32;
    let mut m_l1 = Vec::new();
    for _ in 0..60 {
        m_l1.push(f_l1(&mut b, 1.0, 1.0 - a));
    }
    for (n, &out) in m_l1.iter().enumerate() {
        // After n+1 samples the baseline is 1 − α^(n+1); M_L1 = α^(n+1).
        let expected = a.powi(n as i32 + 1);
        assert!((out - expected).abs() < 1e-5, "n={n}: {out} vs {expected}");
    }
    // 10 % decay after T: M_L1 has fallen to 10 % of the step after r·T samples.
    assert!((m_l1[19] - 0.1).abs() < 1e-4, "{}", m_l1[19]);
}

#[test]
fn f_l1_impulse_passes_whole_and_the_baseline_decays_analytically() {
    let a = 0.9f32;
    let mut b = 0.0f32;
    // Impulse of height 1 at n = 0.
    let out = f_l1(&mut b, 1.0, 1.0 - a);
    assert!(
        (out - a).abs() < 1e-6,
        "impulse passes with α of its height"
    );
    assert!((b - (1.0 - a)).abs() < 1e-6);
    for n in 1..30 {
        let out = f_l1(&mut b, 0.0, 1.0 - a);
        // Rectified: the negative after-swing of a linear high-pass is removed.
        assert_eq!(out, 0.0);
        let expected = (1.0 - a) * a.powi(n);
        assert!((b - expected).abs() < 1e-6, "n={n}: {b} vs {expected}");
    }
}

#[test]
fn f_s1_step_and_impulse_responses_match_the_analytic_ema() {
    let a = alpha(20.0, 1.0) as f32;
    // Step: S1(n) = 1 − α^(n+1); S2(n) = max(0, 1 − S1(n−1)) = α^n.
    let mut s1 = 0.0f32;
    for n in 0..100 {
        let s2 = f_s1(&mut s1, 1.0, a);
        assert!((s1 - (1.0 - a.powi(n + 1))).abs() < 1e-5, "n={n}");
        assert!((s2 - a.powi(n)).abs() < 1e-5, "n={n}");
    }
    // 10 % decay after T = 20 samples of zero input.
    let peak = s1;
    for _ in 0..20 {
        let s2 = f_s1(&mut s1, 0.0, a);
        assert_eq!(s2, 0.0, "activity leaving is not moving activity");
    }
    assert!((s1 / peak - 0.1).abs() < 1e-4, "{}", s1 / peak);
    // Impulse: S1 jumps by (1−α) and decays by α per second; S2 takes the impulse.
    let mut s1 = 0.0f32;
    let s2 = f_s1(&mut s1, 1.0, a);
    assert_eq!(s2, 1.0);
    for n in 1..40 {
        f_s1(&mut s1, 0.0, a);
        assert!((s1 - (1.0 - a) * a.powi(n)).abs() < 1e-6, "n={n}");
    }
}

#[test]
fn f_l2_is_mean_and_population_variance_during_warm_up_then_ema() {
    let a = alpha(10.0, 1.0);
    let xs = [2.0f32, 4.0, 4.0, 5.0];
    let (mut mean, mut var) = (0.0f32, 0.0f32);
    for (n, &x) in xs.iter().enumerate() {
        // 1 − α = 0.206: the first four weights 1, 1/2, 1/3, 1/4 are all larger.
        f_l2(
            &mut mean,
            &mut var,
            x,
            warmup_weight(1.0 - a, n as u64) as f32,
        );
    }
    assert!((mean - 3.75).abs() < 1e-6, "{mean}");
    // Population variance of 2, 4, 4, 5: (1.75² + 0.25² + 0.25² + 1.25²) / 4.
    assert!((var - 1.1875).abs() < 1e-5, "{var}");

    // Later: the EMA step response, mean → x with weight 1−α per sample.
    let w = (1.0 - a) as f32;
    let (mut mean, mut var) = (0.0f32, 0.0f32);
    for n in 1..=30 {
        f_l2(&mut mean, &mut var, 1.0, w);
        let expected = 1.0 - (a as f32).powi(n);
        assert!((mean - expected).abs() < 1e-5, "n={n}");
    }
    // After T = 10 days the model has moved 90 % of the way.
    let (mut mean, mut var) = (0.0f32, 0.0f32);
    for _ in 0..10 {
        f_l2(&mut mean, &mut var, 1.0, w);
    }
    assert!((mean - 0.9).abs() < 2e-3, "{mean}");
    assert!(var >= 0.0);
}

#[test]
fn flow_is_scaled_by_the_fraction_that_passes() {
    assert_eq!(pass_fraction(0.0, 0.0), 0.0);
    assert_eq!(pass_fraction(0.5, 0.25), 0.5);
    assert_eq!(pass_fraction(0.5, 0.5), 1.0);
}

#[test]
fn rate_estimator_is_robust_to_gaps_jitter_and_repeats() {
    let mut r = RateEstimator::default();
    let period = 1_000_000_000 / 25;
    let mut t = 0i64;
    assert_eq!(r.push(t), None);
    for i in 1..100 {
        // ±10 % jitter, a 10-s gap and a repeated timestamp.
        t += if i == 50 {
            10_000_000_000
        } else if i == 60 {
            0
        } else {
            period
                + if i % 2 == 0 {
                    period / 10
                } else {
                    -period / 10
                }
        };
        r.push(t);
    }
    let rate = r.rate().unwrap();
    assert!((rate - 25.0).abs() < 0.5, "{rate}");
    r.reset();
    assert_eq!(r.rate(), None);
}

fn random_frame(rng: &mut Lcg, blocks: usize) -> Vec<BlockMotion> {
    (0..blocks)
        .map(|_| {
            let on = rng.f32() < 0.3;
            let d = if on { rng.f32() } else { 0.0 };
            let (ux, uy) = (rng.f32() * 2.0 - 1.0, rng.f32() * 2.0 - 1.0);
            BlockMotion {
                density: d,
                dx: d * ux * 0.7,
                dy: d * uy * 0.7,
                ..Default::default()
            }
        })
        .collect()
}

#[test]
fn cascade_and_non_cascade_banks_agree_and_the_cascade_is_cheaper() {
    let blocks = 37;
    let mut rng = Lcg::with_seed(7);
    // Both on the counting number type: each bank's operations are counted as it
    // runs (on this thread, one bank at a time).
    let mut c = CascadeBank::<Counted>::new(blocks);
    let mut nc = NonCascadeBank::<Counted>::new(blocks);
    let (mut ops_c, mut ops_nc) = (OpCount::default(), OpCount::default());
    let add = |sum: &mut OpCount, n: OpCount| {
        sum.add += n.add;
        sum.mul += n.mul;
        sum.div += n.div;
        sum.max += n.max;
    };
    let (mut oc, mut onc) = (
        vec![BlockActivity::default(); blocks],
        vec![BlockActivity::default(); blocks],
    );
    let a = alpha(20.0, 1.0) as f32;
    let (mut mc, mut mnc) = (vec![0.0; blocks], vec![0.0; blocks]);
    let mut frames_in_minute = 0;
    Counted::take();
    for second in 0..600u32 {
        let frames = 5 + second % 4;
        for f in 0..frames {
            let frame = random_frame(&mut rng, blocks);
            let w = warmup_weight(1.0 - 0.999, (second * 10 + f) as u64) as f32;
            c.frame(&frame, w);
            add(&mut ops_c, Counted::take());
            nc.frame(&frame, w);
            add(&mut ops_nc, Counted::take());
        }
        frames_in_minute += frames;
        let input = SecondInput {
            frames,
            gap_decay: if second % 97 == 0 { 0.5 } else { 1.0 },
            alpha_s1: a,
        };
        c.second(input, &mut oc);
        add(&mut ops_c, Counted::take());
        nc.second(input, &mut onc);
        add(&mut ops_nc, Counted::take());
        assert_eq!(oc, onc, "second {second}: short-term outputs differ");
        if second % 60 == 59 {
            c.minute_mean(frames_in_minute, &mut mc);
            add(&mut ops_c, Counted::take());
            nc.minute_mean(frames_in_minute, &mut mnc);
            add(&mut ops_nc, Counted::take());
            frames_in_minute = 0;
            for k in 0..blocks {
                assert!(
                    (mc[k] - mnc[k]).abs() <= 1e-5 * mnc[k].abs().max(1e-3),
                    "minute mean of block {k}: {} vs {}",
                    mc[k],
                    mnc[k]
                );
            }
        }
    }
    assert!(oc.iter().any(|o| o.s1 > 0.0) && oc.iter().any(|o| o.s2 > 0.0));
    assert_eq!(c.baseline(), nc.baseline());
    assert!(c.state_bytes() < nc.state_bytes());
    // Per block-frame the cascade adds into one set of sums instead of three:
    // fewer additions; per second it runs F_S1 once for both outputs.
    assert!(ops_c.add < ops_nc.add, "{ops_c:?} vs {ops_nc:?}");
    assert!(ops_c.total() < ops_nc.total(), "{ops_c:?} vs {ops_nc:?}");
    // The same F_L1 and pass fraction per block-frame in both.
    assert_eq!(ops_c.div, ops_nc.div);
}

#[test]
fn counted_counts_what_it_computes_and_agrees_with_f32() {
    Counted::take();
    let (mut b, mut bc) = (0.25f32, Counted(0.25));
    let plain = f_l1(&mut b, 0.75, 0.5);
    let counted = f_l1(&mut bc, Counted(0.75), Counted(0.5));
    assert_eq!((plain, b), (counted.0, bc.0));
    // b += w·(m − b): sub, mul, add; then max(0, m − b): sub, max.
    assert_eq!(
        Counted::take(),
        OpCount {
            add: 3,
            mul: 1,
            div: 0,
            max: 1
        }
    );
    assert_eq!(Counted::take(), OpCount::default(), "take starts again");
}

#[test]
fn reset_short_term_keeps_the_baseline() {
    let mut c = CascadeBank::<f32>::new(2);
    let frame = vec![
        BlockMotion {
            density: 0.5,
            ..Default::default()
        };
        2
    ];
    c.frame(&frame, 1.0);
    let mut out = vec![BlockActivity::default(); 2];
    c.second(
        SecondInput {
            frames: 1,
            gap_decay: 1.0,
            alpha_s1: 0.5,
        },
        &mut out,
    );
    c.reset_short_term();
    assert_eq!(c.baseline(), [0.5, 0.5]);
    assert!(c.s1.iter().all(|&v| v == 0.0));
}
