use super::*;
use isochron_wire::{CameraId, Preamble, Stream};

const GRID: (u32, u32) = (4, 2); // 64x32 px at 16 px blocks

fn header(second: i64, model_days: u32) -> ActivityHeader {
    let mut preamble =
        Preamble::new::<BlockActivity>(Stream::Activity, CameraId::new("c").unwrap(), 0, 8);
    preamble.capture_time_ns = (second + 1) * NS_PER_S;
    ActivityHeader {
        preamble,
        grid_w: GRID.0,
        grid_h: GRID.1,
        block_px: 16,
        frame_width: 64,
        frame_height: 32,
        t_star: 0,
        model_days,
        frames: 10,
        first_source_index: second as u64 * 10,
        last_source_index: second as u64 * 10 + 9,
        frame_rate: 10.0,
        reserved: 0,
    }
}

fn blocks(s2_block_1: f32, lt_mean: f32, lt_sigma: f32) -> Vec<BlockActivity> {
    let mut v = vec![
        BlockActivity {
            lt_mean,
            lt_sigma,
            ..Default::default()
        };
        8
    ];
    v[1].s2 = s2_block_1;
    v
}

fn gate(config: GateConfig) -> Gate {
    Gate::new(
        GateSettings {
            gate: config,
            warm_days: 3,
        },
        Vec::new(),
    )
}

/// Feeds second `s` with `b`, answering each detection job at once with
/// `found` (the boxes on the second's last frame); returns the actions.
fn feed(g: &mut Gate, s: i64, b: &[BlockActivity], found: &[Detection]) -> Vec<Action> {
    let actions = g.on_activity(&header(s, 0), b);
    for a in &actions {
        if let Action::Detect(job) = a {
            let result = Found {
                capture_time_ns: job.time_ns,
                source_index: s as u64 * 10 + 9,
                detections: found,
            };
            g.on_detections(job.id, job.region, Some(result));
        }
    }
    actions
}

/// A person box standing on blocks 1 and 5 (feet in block 5).
fn person() -> Detection {
    Detection {
        x: 18.0,
        y: 2.0,
        w: 10.0,
        h: 28.0,
        score: 1.0,
        class: 0,
        ..Default::default()
    }
}

fn kinds(actions: &[Action]) -> Vec<String> {
    actions
        .iter()
        .map(|a| match a {
            Action::Event { phase, event, .. } => format!("{phase:?}#{}", event.id),
            Action::Detect(j) => format!("Detect#{}", j.event_id),
        })
        .collect()
}

#[test]
fn floor_before_warm_and_k_sigma_after() {
    // Cold: floor 0.5 → 0.6 starts a moving event.
    let mut g = gate(GateConfig::default());
    let a = g.on_activity(&header(0, 0), &blocks(0.6, 0.0, 0.0));
    assert_eq!(kinds(&a), ["Detect#0", "Start#0"]);
    // Warm with mean 0.1/block (0.8 zone) and sigma 0.05/block (zone sigma
    // sqrt(8)·0.05 ≈ 0.141, ×3 = 0.424): threshold ≈ 1.22 → 0.6 starts nothing.
    let mut g = gate(GateConfig::default());
    assert!(
        g.on_activity(&header(0, 5), &blocks(0.6, 0.1, 0.05))
            .is_empty()
    );
    let a = g.on_activity(&header(1, 5), &blocks(1.3, 0.1, 0.05));
    assert_eq!(kinds(&a), ["Detect#0", "Start#0"]);
}

#[test]
fn a_present_block_holds_the_event_which_ends_when_nothing_is_present() {
    let mut g = gate(GateConfig {
        detector: isochron_config::DetectorConfig {
            enabled: false,
            ..Default::default()
        },
        ..GateConfig::default()
    });
    let mut all = Vec::new();
    for s in 0..40 {
        // Moving 5..8 s, then still but present until 30 s.
        let mut b = blocks(if (5..8).contains(&s) { 1.0 } else { 0.0 }, 0.0, 0.0);
        if (5..30).contains(&s) {
            b[1].present = 1.0;
        }
        all.extend(g.on_activity(&header(s, 0), &b));
    }
    // No detector: no jobs; one event, ended at the first second with nothing
    // present (its activity was quiet for longer than the hold).
    assert_eq!(kinds(&all), ["Start#0", "End#0"]);
    let Action::Event { event, .. } = &all[1] else {
        panic!()
    };
    assert_eq!((event.start_frame, event.end_frame), (50, 299));
}

#[test]
fn one_detection_per_event_by_default_and_none_without_events() {
    let mut g = gate(GateConfig::default());
    let mut all = Vec::new();
    for s in 0..30 {
        let on = (5..12).contains(&s) || (20..22).contains(&s);
        all.extend(feed(
            &mut g,
            s,
            &blocks(if on { 1.0 } else { 0.0 }, 0.0, 0.0),
            &[],
        ));
    }
    // Each event: a detection when it starts, one more when it falls quiet
    // (does someone stay?), which finds nobody.
    assert_eq!(
        kinds(&all),
        [
            "Detect#0", "Start#0", "Detect#0", "End#0", "Detect#1", "Start#1", "Detect#1", "End#1"
        ]
    );
    let Action::Event { event, .. } = &all[3] else {
        panic!()
    };
    assert_eq!((event.start_frame, event.end_frame), (50, 119));
    assert_eq!(event.blocks, vec![1]);
}

#[test]
fn n_per_event_and_every_m_seconds() {
    let run = |config: GateConfig| {
        let mut g = gate(config);
        let mut detects = 0;
        for s in 0..20 {
            let a = feed(
                &mut g,
                s,
                &blocks(if s < 10 { 1.0 } else { 0.0 }, 0.0, 0.0),
                &[],
            );
            detects += a.iter().filter(|a| matches!(a, Action::Detect(_))).count();
        }
        detects - 1 // the check when the event falls quiet
    };
    assert_eq!(
        run(GateConfig {
            detect_per_event: 3,
            ..GateConfig::default()
        }),
        3
    );
    // Ten seconds of event, one every 4 s: at 0, 4 and 8.
    assert_eq!(
        run(GateConfig {
            detect_every_s: Some(4.0),
            ..GateConfig::default()
        }),
        3
    );
}

#[test]
fn zones_only_see_their_blocks() {
    // A zone over the right half (blocks 2, 3, 6, 7): activity in block 1 is
    // outside it.
    let zone = ZoneConfig {
        name: "right".into(),
        polygon: vec![[32.0, 0.0], [64.0, 0.0], [64.0, 32.0], [32.0, 32.0]],
    };
    let mut g = Gate::new(
        GateSettings {
            gate: GateConfig::default(),
            warm_days: 3,
        },
        vec![zone],
    );
    assert!(
        g.on_activity(&header(0, 0), &blocks(5.0, 0.0, 0.0))
            .is_empty()
    );
    let mut b = blocks(0.0, 0.0, 0.0);
    b[6].s1 = 0.7;
    let a = g.on_activity(&header(1, 0), &b);
    let Some(Action::Event { zone, event, .. }) = a.last() else {
        panic!()
    };
    assert_eq!(
        (zone.as_str(), event.kind, event.blocks.clone()),
        ("right", ActivityKind::InPlace, vec![6])
    );
}

#[test]
fn passers_by_tails_are_not_in_place_activity() {
    // Eight blocks each with a small decaying S1 tail (0.04 < 0.05): together
    // 0.32 — but no block has lasting activity, so no in-place event.
    let mut g = gate(GateConfig {
        floor: 0.3,
        ..GateConfig::default()
    });
    let mut b = blocks(0.0, 0.0, 0.0);
    b.iter_mut().for_each(|b| b.s1 = 0.04);
    assert!(g.on_activity(&header(0, 0), &b).is_empty());
    // One block where someone stands: in place.
    b[3].s1 = 0.4;
    let a = g.on_activity(&header(1, 0), &b);
    let Some(Action::Event { event, .. }) = a.last() else {
        panic!("{a:?}")
    };
    assert_eq!(
        (event.kind, event.blocks.clone()),
        (ActivityKind::InPlace, vec![3])
    );
}

/// Walks in (moving activity in block 1 for 5 s), then stands still (no
/// activity at all) until `leaves`; the detector sees the person on every
/// frame before `leaves`. Returns the actions per second.
fn stand_still(config: GateConfig, leaves: i64, seconds: i64) -> (Gate, Vec<(i64, Action)>) {
    let mut g = gate(config);
    let mut out = Vec::new();
    for s in 0..seconds {
        let mut b = blocks(if s < 5 { 1.0 } else { 0.0 }, 0.0, 0.0);
        // S1 decays after the walk: the blocks stay weakly active a while.
        if (5..15).contains(&s) {
            b[1].s1 = 0.2 * 0.9f32.powi(s as i32 - 4);
            b[5].s1 = b[1].s1;
        }
        let found = if s < leaves { vec![person()] } else { vec![] };
        out.extend(feed(&mut g, s, &b, &found).into_iter().map(|a| (s, a)));
    }
    (g, out)
}

#[test]
fn a_confirmed_person_keeps_the_event_open_until_a_recheck_misses_them() {
    let (g, actions) = stand_still(GateConfig::default(), 40, 60);
    let detects: Vec<i64> = actions
        .iter()
        .filter(|(_, a)| matches!(a, Action::Detect(_)))
        .map(|(s, _)| *s)
        .collect();
    // At the start; then re-checks every 5 s while confirmed; the one at 40
    // finds nobody.
    assert_eq!(detects, [0, 5, 10, 15, 20, 25, 30, 35, 40], "{actions:?}");
    let ends: Vec<&(i64, Action)> = actions
        .iter()
        .filter(|(_, a)| {
            matches!(
                a,
                Action::Event {
                    phase: EventPhase::End,
                    ..
                }
            )
        })
        .collect();
    assert_eq!(ends.len(), 1, "one event for the whole stay: {actions:?}");
    let (when, Action::Event { event, .. }) = ends[0] else {
        panic!()
    };
    // Last seen on the last frame of second 35 (a re-check); the re-check of
    // second 40 misses them, and the hold after 36 s has passed: the event
    // ends with the next second.
    assert_eq!((*when, event.end_frame), (41, 359));
    assert_eq!(g.confirmed(), 0);
}

#[test]
fn a_check_when_activity_falls_quiet_finds_who_stays() {
    // The start detection misses the person (the detector sees them only from
    // second 3 on): the check when the walk's activity falls quiet (second 5)
    // confirms them; re-checks at 10, 15, 20 find them, the one at 25 does
    // not.
    let mut g = gate(GateConfig::default());
    let mut ends = Vec::new();
    for s in 0..30 {
        let mut b = blocks(if s < 5 { 1.0 } else { 0.0 }, 0.0, 0.0);
        b[5].s1 = if s < 15 { 0.1 } else { 0.0 };
        let found = if (3..25).contains(&s) {
            vec![person()]
        } else {
            vec![]
        };
        for a in feed(&mut g, s, &b, &found) {
            if let Action::Event {
                phase: EventPhase::End,
                event,
                ..
            } = a
            {
                ends.push((s, event.end_frame));
            }
        }
    }
    assert_eq!(ends, [(26, 209)], "held open while the person stayed");
}

#[test]
fn a_detector_hit_where_nothing_moved_confirms_nobody() {
    // A "person" on block 3 and 7, which never move: no confirmation.
    let ghost = Detection {
        x: 50.0,
        ..person()
    };
    let mut g = gate(GateConfig::default());
    let mut ended_at = None;
    for s in 0..20 {
        let b = blocks(if s < 5 { 1.0 } else { 0.0 }, 0.0, 0.0);
        for a in feed(&mut g, s, &b, &[ghost]) {
            if let Action::Event {
                phase: EventPhase::End,
                ..
            } = a
            {
                ended_at = Some(s);
            }
        }
    }
    assert_eq!(
        ended_at,
        Some(7),
        "ends after the hold as without a detector"
    );
    assert_eq!(g.confirmed(), 0);
}

#[test]
fn events_never_wait_for_the_detector_and_a_dropped_recheck_is_retried() {
    let mut g = gate(GateConfig::default());
    let a = g.on_activity(&header(0, 0), &blocks(1.0, 0.0, 0.0));
    let Some(Action::Detect(start)) = a.first().cloned() else {
        panic!("{a:?}")
    };
    // Quiet, and the start job has not reported: the event ends after the
    // hold all the same.
    let mut ended = 0;
    for s in 1..10 {
        let a = g.on_activity(&header(s, 0), &blocks(0.0, 0.0, 0.0));
        ended += a
            .iter()
            .filter(|a| matches!(a, Action::Event { .. }))
            .count();
    }
    assert_eq!((ended, g.open_events()), (1, 0));
    let found = Found {
        capture_time_ns: start.time_ns,
        source_index: 9,
        detections: &[person()],
    };
    g.on_detections(start.id, start.region, Some(found));
    assert_eq!(g.confirmed(), 1, "a person on block 1, active in second 0");
    // Confirmed: a re-check at once; it is dropped, so it is asked again.
    let detect = |a: Vec<Action>| match a.as_slice() {
        [Action::Detect(job)] => *job,
        _ => panic!("{a:?}"),
    };
    let recheck = detect(g.on_activity(&header(10, 0), &blocks(0.0, 0.0, 0.0)));
    g.on_detections(recheck.id, recheck.region, None);
    assert_eq!(g.confirmed(), 1, "a check that did not run changes nothing");
    let recheck = detect(g.on_activity(&header(11, 0), &blocks(0.0, 0.0, 0.0)));
    let nobody = Found {
        capture_time_ns: recheck.time_ns,
        source_index: 119,
        detections: &[],
    };
    g.on_detections(recheck.id, recheck.region, Some(nobody));
    assert_eq!(g.confirmed(), 0);
    assert!(
        g.on_activity(&header(12, 0), &blocks(0.0, 0.0, 0.0))
            .is_empty()
    );
}

#[test]
fn a_person_nothing_moves_under_is_confirmed_only_for_confirm_still_max_s() {
    // The detector finds the person for ever (a poster it likes); the last
    // activity under their box is in second 14 (the walk's S1 tail).
    let (g, actions) = stand_still(
        GateConfig {
            confirm_still_max_s: 20.0,
            ..GateConfig::default()
        },
        i64::MAX,
        60,
    );
    let ends: Vec<(i64, u64)> = actions
        .iter()
        .filter_map(|(s, a)| match a {
            Action::Event {
                phase: EventPhase::End,
                event,
                ..
            } => Some((*s, event.end_frame)),
            _ => None,
        })
        .collect();
    // Dropped in second 34 (20 s after the end of second 14); the event had
    // been extended to the re-check of second 30 and ends now, its hold long
    // past. The closing check finds the "person" again, on blocks that did
    // not move: nobody is confirmed.
    assert_eq!(ends, [(34, 309)], "{actions:?}");
    assert_eq!((g.confirmed(), g.open_events()), (0, 0));
    // By default (300 s) the same minute keeps them confirmed.
    let (g, _) = stand_still(GateConfig::default(), i64::MAX, 60);
    assert_eq!((g.confirmed(), g.open_events()), (1, 1));
}

#[test]
fn the_detector_searches_a_crop_around_activity_and_confirmed_people() {
    let grid = BlockGrid::new(64, 32, 16);
    // Block 1 is x 16..32, y 0..16; 8 px more on each side, clamped.
    assert_eq!(
        crop_region(&grid, &[1], &[], 8),
        Region {
            x: 8,
            y: 0,
            w: 32,
            h: 24
        }
    );
    let p = Person {
        bbox: [40.5, 10.0, 10.0, 12.2],
        seen_ns: 0,
        active_ns: 0,
    };
    assert_eq!(
        crop_region(&grid, &[1], &[p], 0),
        Region {
            x: 16,
            y: 0,
            w: 35,
            h: 23
        }
    );
    assert_eq!(crop_region(&grid, &[], &[], 8), Region::WHOLE, "nothing");
    assert_eq!(crop_region(&grid, &[0, 7], &[], 0), Region::WHOLE, "all");
    // The gate's jobs carry it: moving activity in block 1 only.
    let mut g = gate(GateConfig {
        detector: isochron_config::DetectorConfig {
            crop_margin_px: 8,
            ..Default::default()
        },
        ..GateConfig::default()
    });
    let a = g.on_activity(&header(0, 0), &blocks(1.0, 0.0, 0.0));
    let Some(Action::Detect(job)) = a.first() else {
        panic!("{a:?}")
    };
    assert_eq!((job.region.x, job.region.w), (8, 32));
    // Without the crop: the whole frame.
    let mut g = gate(GateConfig {
        detector: isochron_config::DetectorConfig {
            crop: false,
            ..Default::default()
        },
        ..GateConfig::default()
    });
    let a = g.on_activity(&header(0, 0), &blocks(1.0, 0.0, 0.0));
    assert!(matches!(a.first(), Some(Action::Detect(j)) if j.region.is_whole()));
}

#[test]
fn blocks_under_a_box() {
    let grid = BlockGrid::new(64, 32, 16);
    let under = |b: [f32; 4]| blocks_under(&grid, &b).collect::<Vec<u32>>();
    assert_eq!(under([18.0, 2.0, 10.0, 28.0]), [1, 5]);
    assert_eq!(under([-5.0, -5.0, 100.0, 100.0]), [0, 1, 2, 3, 4, 5, 6, 7]);
    assert_eq!(under([16.0, 0.0, 16.0, 16.0]), [1], "edges are exclusive");
}

#[test]
fn finish_closes_open_events() {
    let mut g = gate(GateConfig::default());
    g.on_activity(&header(0, 0), &blocks(1.0, 0.0, 0.0));
    assert_eq!(g.open_events(), 1);
    assert_eq!(kinds(&g.finish()), ["End#0"]);
    assert_eq!(g.open_events(), 0);
}
