//! Costs, curves and rankings of segments and routes.

use super::*;
use isochron_config::clock::Cycle;
use isochron_store::{Bin, StoreMeta};
use isochron_wire::BlockActivity;

fn params() -> CostParams {
    CostParams {
        weight_in_place: 1.0,
        weight_moving: 1.0,
        weight_long_term: 0.5,
        cost_scale: 0.1,
        cap: 100,
        confirm_cost: 100,
        confirm_radius_m: 0.5,
        presence_cost: 60,
    }
}

fn profile(name: &str, f: impl Fn(u32) -> Option<f64>) -> SegmentProfile {
    let m_p: Vec<Option<f64>> = (0..1440).map(f).collect();
    SegmentProfile {
        name: name.into(),
        m_prime: m_p.iter().flatten().any(|&m| m > 0.0),
        m_p,
    }
}

fn route(name: &str, segments: &[&str]) -> RouteConfig {
    RouteConfig {
        name: name.into(),
        segments: segments.iter().map(|s| s.to_string()).collect(),
    }
}

#[test]
fn the_quiet_hour_is_the_cheapest_window() {
    // Busy all day except 12:00-13:00 on segment a; b is always a little busy.
    let a = profile("a", |m| {
        Some(if (720..780).contains(&m) { 0.0 } else { 0.08 })
    });
    let b = profile("b", |_| Some(0.01));
    let r = route("r", &["a", "b"]);
    let plan = plan_offline(&r, &[&a, &b], DayRange::whole_day(5), &params());
    assert_eq!(plan.curve.len(), 288);
    assert!(plan.never_active.is_empty());
    assert_eq!(
        plan.windows[0],
        Window {
            start: 720,
            end: 780,
            cost: 10.0
        }
    );
    assert_eq!(plan.windows.len(), 1);
    assert_eq!(plan.best[0].minute, 720);
    assert!((plan.curve[0].cost - 90.0).abs() < 1e-9);
    // Within a narrower range, and with a step that straddles the window's edge.
    let range = DayRange {
        start: 11 * 60,
        end: 14 * 60,
        step: 7,
        cycle_offset: 0,
    };
    let plan = plan_offline(&r, &[&a, &b], range, &params());
    assert_eq!(plan.curve.first().unwrap().minute, 660);
    let w = plan.windows[0];
    assert!(w.start >= 720 && w.end <= 780 + 7, "{w:?}");
}

#[test]
fn a_never_visited_segment_makes_the_route_infinite() {
    let a = profile("a", |_| Some(0.05));
    let dead = profile("dead", |_| Some(0.0));
    assert!(!dead.m_prime);
    let r = route("r", &["a", "dead"]);
    assert_eq!(cost1(&[&a, &dead], 600, &params()), f64::INFINITY);
    let plan = plan_offline(&r, &[&a, &dead], DayRange::whole_day(60), &params());
    assert_eq!(plan.never_active, vec!["dead".to_string()]);
    assert!(plan.curve.iter().all(|p| p.cost == f64::INFINITY));
    assert!(plan.windows.is_empty() && plan.best.is_empty());
    // Missing data is unknown, not free.
    let gap = profile("gap", |m| (m >= 60).then_some(0.02));
    assert!(cost1(&[&gap], 30, &params()).is_nan());
    assert!((cost1(&[&gap], 90, &params()) - 20.0).abs() < 1e-9);
}

#[test]
fn now_ranks_by_the_weighted_sum() {
    // Long-term: x is quiet, y busy at 10:00. Short-term now: x busy, y quiet.
    let x = profile("x", |_| Some(0.01)); // Cost 10
    let y = profile("y", |_| Some(0.05)); // Cost 50
    let dead = profile("dead", |_| Some(0.0));
    let rx = route("via-x", &["x"]);
    let ry = route("via-y", &["y"]);
    let rd = route("via-dead", &["dead"]);
    let mut now = BTreeMap::new();
    now.insert("x".to_string(), Some(0.08)); // Cost 80
    now.insert("y".to_string(), Some(0.0)); // Cost 0
    let routes = vec![(&rx, vec![&x]), (&ry, vec![&y]), (&rd, vec![&dead])];
    // Long-term dominates: x (10) before y (50).
    let ranked = plan_now(&routes, &now, 600, &params(), 1.0, 0.1);
    let names: Vec<&str> = ranked.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(names, ["via-x", "via-y", "via-dead"]);
    assert!((ranked[0].cost2 - (10.0 + 0.1 * 80.0)).abs() < 1e-9);
    assert!(ranked[2].infinite && ranked[2].cost2.is_infinite());
    // Short-term dominates: y (50·0.1 + 0) before x (10·0.1 + 80).
    let ranked = plan_now(&routes, &now, 600, &params(), 0.1, 1.0);
    let names: Vec<&str> = ranked.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(names, ["via-y", "via-x", "via-dead"]);
    assert!((ranked[0].cost2 - 5.0).abs() < 1e-9);
    assert!((ranked[1].cost2 - 81.0).abs() < 1e-9);
    // No live data: the long-term mean stands in, flagged.
    let ranked = plan_now(
        &[(&rx, vec![&x])],
        &BTreeMap::new(),
        600,
        &params(),
        1.0,
        1.0,
    );
    assert!(ranked[0].estimated);
    assert!((ranked[0].cost2 - 20.0).abs() < 1e-9);
}

#[test]
fn profiles_average_the_segment_blocks_of_learned_bins() {
    let meta = StoreMeta::new("cam01", BlockGrid::new(32, 16, 16), Cycle::Daily, 0);
    let bin = Bin {
        t_star: 100,
        count: 3,
        last_minute: 0,
        mean: vec![0.2, 0.4],
        var: vec![0.0, 0.0],
    };
    let model = Model::with_bins(meta, [bin]);
    let seg = SegmentBlocks {
        name: "s".into(),
        blocks: vec![(0, vec![0, 1])],
    };
    let p = SegmentProfile::from_models(&seg, &[Some(&model)], 1440, 0.0);
    assert!((p.at(100).unwrap() - 0.3).abs() < 1e-6);
    assert_eq!(p.at(101), None);
    assert!(p.m_prime);
    let p = SegmentProfile::from_models(&seg, &[Some(&model)], 1440, 0.5);
    assert!(!p.m_prime, "nothing above min_activity");
    // Short-term: mean over the live blocks.
    let live = [
        BlockActivity {
            s1: 0.1,
            ..Default::default()
        },
        BlockActivity {
            s2: 0.3,
            ..Default::default()
        },
    ];
    let now = segment_now(&seg, &[Some(&live[..])], &params()).unwrap();
    assert!((now - 0.2).abs() < 1e-6);
    assert_eq!(segment_now(&seg, &[None], &params()), None);
    assert_eq!(store_block_grid(&model).grid_w(), 2);
}
