//! The band on synthetic block scenes: a textured empty floor, objects that enter
//! with motion, stay, leave; light changes; ghosts.

use super::*;
use isochron_wire::{APPEARANCE_SCALE, BlockMotion, FLAG_APPEARANCE};

const W: usize = 12;
const H: usize = 8;

/// A scene of `W × H` blocks: each block's appearance (luma, texture) in grey
/// levels, and which blocks move this frame.
#[derive(Clone)]
struct Scene {
    luma: Vec<f32>,
    texture: Vec<f32>,
    moving: Vec<bool>,
}

impl Scene {
    /// The empty floor: lumas 60..=180 and textures 2..=10 varying smoothly.
    fn floor() -> Scene {
        let k = W * H;
        Scene {
            luma: (0..k)
                .map(|i| 60.0 + 120.0 * ((i % W) as f32 / W as f32) + 5.0 * ((i / W) % 2) as f32)
                .collect(),
            texture: (0..k).map(|i| 2.0 + (i % 5) as f32 * 2.0).collect(),
            moving: vec![false; k],
        }
    }

    fn blocks(&self) -> Vec<BlockMotion> {
        (0..W * H)
            .map(|k| BlockMotion {
                density: if self.moving[k] { 0.2 } else { 0.0 },
                luma: (self.luma[k] * APPEARANCE_SCALE as f32).round() as u16,
                texture: (self.texture[k] * APPEARANCE_SCALE as f32).round() as u16,
                ..BlockMotion::default()
            })
            .collect()
    }

    /// An object (bright, textured) over the blocks of `rect` = (x0, y0, w, h).
    fn with_object(&self, rect: (usize, usize, usize, usize)) -> Scene {
        let mut s = self.clone();
        for k in blocks_of(rect) {
            s.luma[k] = 220.0;
            s.texture[k] = 14.0;
        }
        s
    }

    fn moving(mut self, rect: (usize, usize, usize, usize)) -> Scene {
        for k in blocks_of(rect) {
            self.moving[k] = true;
        }
        self
    }

    /// Every luma × `gain` (saturating at 255), textures × `gain`.
    fn lit(&self, gain: f32) -> Scene {
        let mut s = self.clone();
        for l in &mut s.luma {
            *l = (*l * gain).min(255.0);
        }
        for t in &mut s.texture {
            *t *= gain;
        }
        s
    }
}

fn blocks_of((x0, y0, w, h): (usize, usize, usize, usize)) -> impl Iterator<Item = usize> {
    (y0..y0 + h).flat_map(move |y| (x0..x0 + w).map(move |x| y * W + x))
}

/// A band and a clock: ten frames per second, appearance on two of them.
struct Rig {
    band: Presence,
    second: i64,
    out: Vec<BlockActivity>,
}

impl Rig {
    fn new(absorb_s: f64) -> Rig {
        Rig {
            band: Presence::new(
                PresenceParams {
                    absorb_s,
                    ..PresenceParams::default()
                },
                W,
                H,
            ),
            second: 0,
            out: vec![BlockActivity::default(); W * H],
        }
    }

    /// One second of `scene`; returns the present blocks.
    fn run(&mut self, scene: &Scene) -> Vec<usize> {
        let blocks = self.band_frames(scene);
        for (i, b) in blocks.iter().enumerate() {
            let flags = if i % 5 == 0 { FLAG_APPEARANCE } else { 0 };
            self.band.frame(flags, b);
        }
        // The cascade's moving activity: where the scene moves.
        for (o, &m) in self.out.iter_mut().zip(&scene.moving) {
            o.s2 = if m { 0.2 } else { 0.0 };
        }
        self.band.second(self.second, &mut self.out);
        self.second += 1;
        self.present()
    }

    fn band_frames(&self, scene: &Scene) -> Vec<Vec<BlockMotion>> {
        (0..10).map(|_| scene.blocks()).collect()
    }

    fn run_for(&mut self, seconds: usize, scene: &Scene) -> Vec<usize> {
        let mut last = Vec::new();
        for _ in 0..seconds {
            last = self.run(scene);
        }
        last
    }

    fn present(&self) -> Vec<usize> {
        (0..W * H).filter(|&k| self.out[k].present > 0.5).collect()
    }
}

const SPOT: (usize, usize, usize, usize) = (4, 3, 2, 3);

/// Something walks in from the left edge over three seconds and stops at SPOT.
fn walk_in(rig: &mut Rig, floor: &Scene) {
    for x in [0, 2] {
        let at = (x, 3, 2, 3);
        rig.run(&floor.with_object(at).moving(at));
    }
    rig.run(&floor.with_object(SPOT).moving(SPOT));
}

#[test]
fn something_that_enters_and_stops_stays_present_then_leaves() {
    let floor = Scene::floor();
    let mut rig = Rig::new(120.0);
    assert!(rig.run_for(20, &floor).is_empty(), "an empty floor");
    walk_in(&mut rig, &floor);
    let spot: Vec<usize> = blocks_of(SPOT).collect();
    // Standing perfectly still for 60 s: present the whole time, and only there.
    for s in 0..60 {
        assert_eq!(
            rig.run(&floor.with_object(SPOT)),
            spot,
            "second {s} of standing"
        );
    }
    // It walks out: the blocks match the floor again within CLEAR_S seconds.
    rig.run(&floor.with_object(SPOT).moving(SPOT));
    let mut cleared = None;
    for s in 0..5 {
        if rig.run(&floor).is_empty() {
            cleared = Some(s + 1);
            break;
        }
    }
    assert_eq!(cleared, Some(CLEAR_S as usize));
    assert_eq!(rig.band.stats().absorbed, 0);
    assert_eq!(rig.band.stats().ghosts, 0);
}

#[test]
fn a_still_object_becomes_background_after_absorb_s_and_small_motion_keeps_it() {
    let floor = Scene::floor();
    let mut rig = Rig::new(30.0);
    rig.run_for(10, &floor);
    walk_in(&mut rig, &floor);
    let object = floor.with_object(SPOT);
    rig.run(&object);
    // Someone who moves a hand every 20 s stays (the region moved).
    for s in 0..60 {
        let scene = if s % 20 == 10 {
            object.clone().moving((4, 3, 1, 1))
        } else {
            object.clone()
        };
        assert!(!rig.run(&scene).is_empty(), "second {s}: still present");
    }
    // Perfectly still from now: background after 30 s (and not before).
    let mut gone = None;
    for s in 0..40 {
        if rig.run(&object).is_empty() {
            gone = Some(s);
            break;
        }
    }
    let gone = gone.expect("absorbed");
    assert!((20..=30).contains(&gone), "absorbed after {gone} s");
    assert_eq!(rig.band.stats().absorbed, 1);
    // Taken away later: the floor differs from the learned object, with motion: a
    // hole in the background, cleared as a ghost.
    rig.run(&object.clone().moving(SPOT));
    let left = rig.run_for(GHOST_S as usize + 2, &floor);
    assert!(left.is_empty(), "{left:?}");
    assert_eq!(rig.band.stats().ghosts, 1);
}

#[test]
fn a_ghost_of_something_present_from_the_start_clears() {
    let floor = Scene::floor();
    let object = floor.with_object(SPOT);
    let mut rig = Rig::new(120.0);
    // In view, still, from the first frame: learned as background, never present.
    assert!(rig.run_for(20, &object).is_empty());
    // It walks out to the right.
    rig.run(&object.clone().moving(SPOT));
    rig.run(&floor.with_object((6, 3, 2, 3)).moving((4, 3, 4, 3)));
    rig.run(&floor.with_object((9, 3, 2, 3)).moving((6, 3, 5, 3)));
    let cleared = (0..10).find(|_| rig.run(&floor).is_empty());
    let cleared = cleared.expect("the ghost cleared within 10 s");
    assert!(cleared <= GHOST_S as usize + 2, "{cleared} s");
    assert!(rig.run_for(10, &floor).is_empty());
    assert_eq!(rig.band.stats().ghosts, 1);
}

#[test]
fn light_steps_and_ramps_make_nothing_present_and_keep_what_is() {
    let floor = Scene::floor();
    let mut rig = Rig::new(300.0);
    rig.run_for(20, &floor);
    // A 30 % step: no motion, nothing present.
    assert!(rig.run_for(10, &floor.lit(1.3)).is_empty());
    // A ramp back down over 10 minutes, someone passing through now and then.
    for s in 0..600 {
        let gain = 1.3 - 0.3 * s as f32 / 600.0;
        let mut scene = floor.lit(gain);
        if s % 60 == 30 {
            scene = scene.moving((0, 0, 2, 2));
        }
        assert!(rig.run(&scene).is_empty(), "second {s} of the ramp");
    }
    // Someone stands through a 30 % step: still present after it, nothing else is.
    walk_in(&mut rig, &floor);
    rig.run_for(5, &floor.with_object(SPOT));
    let lit = floor.with_object(SPOT).lit(1.3);
    let spot: Vec<usize> = blocks_of(SPOT).collect();
    assert_eq!(rig.run_for(10, &lit), spot);
}

#[test]
fn the_global_fit_recovers_gain_and_offset_despite_outliers() {
    let mut pairs: Vec<(f32, f32)> = (0..100)
        .map(|i| {
            let b = 20.0 + 2.0 * i as f32;
            (b, 1.2 * b + 10.0)
        })
        .collect();
    // A fifth of the blocks are something else.
    for p in pairs.iter_mut().step_by(5) {
        p.1 = 250.0;
    }
    let (g, c) = fit_light(&mut pairs);
    assert!((g - 1.2).abs() < 0.05 && (c - 10.0).abs() < 4.0, "{g} {c}");
}

#[test]
fn blocks_moving_at_the_start_are_learned_once_still_and_the_band_can_be_off() {
    let floor = Scene::floor();
    let mut rig = Rig::new(120.0);
    // Something walks about from the first frame, then leaves.
    let at = (0, 0, 3, 3);
    rig.run_for(5, &floor.with_object(at).moving(at));
    assert!(rig.run_for(10, &floor).is_empty());
    let mut off = Presence::new(
        PresenceParams {
            enabled: false,
            ..PresenceParams::default()
        },
        W,
        H,
    );
    let mut out = vec![BlockActivity::default(); W * H];
    off.frame(
        FLAG_APPEARANCE,
        &floor.with_object(SPOT).moving(SPOT).blocks(),
    );
    off.second(0, &mut out);
    assert!(out.iter().all(|b| b.present == 0.0));
}

#[test]
fn someone_walking_through_is_present_where_they_are_and_leaves_no_trail() {
    let floor = Scene::floor();
    let mut rig = Rig::new(120.0);
    rig.run_for(10, &floor);
    // Across the view, a block pair per second, then gone.
    for x in (0..W - 1).step_by(2) {
        let at = (x, 3, 2, 3);
        let present = rig.run(&floor.with_object(at).moving(at));
        assert_eq!(present, blocks_of(at).collect::<Vec<_>>(), "at {x}");
    }
    assert!(rig.run(&floor).is_empty());
    assert_eq!(rig.band.stats().ghosts, 0);
}

#[test]
fn a_restless_block_never_has_something_enter_and_an_arm_that_moves_joins_its_body() {
    let floor = Scene::floor();
    let mut rig = Rig::new(120.0);
    // A flag in the wind at (10, 0): it moves four seconds in five and looks
    // different each time it settles.
    let flag = (10, 0, 1, 1);
    let flagged = |rig: &mut Rig, s: usize, scene: &Scene| {
        let mut scene = scene.clone();
        if !s.is_multiple_of(5) {
            scene = scene.moving(flag);
        }
        scene.luma[10] = 100.0 + 30.0 * (s % 3) as f32;
        rig.run(&scene)
    };
    // Once the band has seen it for a few seconds (at the start, nothing is
    // known to be restless).
    for s in 0..120 {
        let present = flagged(&mut rig, s, &floor);
        assert!(s < 5 || present.is_empty(), "second {s}");
    }
    // Someone walks in and stands; one arm block moves every second.
    walk_in(&mut rig, &floor);
    let arm = (5, 3, 1, 1);
    let spot: Vec<usize> = blocks_of(SPOT).collect();
    let mut last = Vec::new();
    for s in 0..5 {
        last = flagged(&mut rig, 120 + s, &floor.with_object(SPOT).moving(arm));
    }
    assert_eq!(last, spot, "the arm joined");
}

#[test]
fn a_change_that_only_coincides_with_motion_next_to_it_does_not_enter() {
    let floor = Scene::floor();
    let mut rig = Rig::new(120.0);
    rig.run_for(10, &floor);
    // Someone walks past block (4, 3) while its light goes down: it differs, a
    // neighbour moves, the block itself does not.
    let mut dimmed = floor.clone().moving((5, 3, 1, 1));
    dimmed.luma[3 * W + 4] -= 40.0;
    let present = rig.run(&dimmed);
    assert!(!present.contains(&(3 * W + 4)), "{present:?}");
    let mut still = floor.clone();
    still.luma[3 * W + 4] -= 40.0;
    assert!(rig.run_for(3, &still).is_empty());
}
