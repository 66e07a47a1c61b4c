//! The gate of one camera: zones, their event trackers, and the choice of frames
//! to detect. Pure logic over activity samples; the service wires it to iceoryx2.

use std::collections::HashMap;

use isochron_shared::clock::NS_PER_S;
use isochron_shared::config::{GateConfig, ZoneConfig};
use isochron_shared::geometry::BlockGrid;
use isochron_shared::wire::{ActivityHeader, ActivityKind, BlockActivity, EventPhase};

use crate::events::{Change, Event, EventTracker, Second, threshold};
use crate::worker::Job;

/// A block counts as involved in an event when its own activity is at least this.
pub const BLOCK_ACTIVE: f32 = 0.01;

/// What the gate asks the service to do.
#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    /// Publish an event record.
    Event {
        /// Start or end.
        phase: EventPhase,
        /// Zone name.
        zone: String,
        /// The event.
        event: Event,
    },
    /// Run the detector.
    Detect(Job),
}

struct Zone {
    config: ZoneConfig,
    blocks: Vec<u32>,
    trackers: [EventTracker; 2],
}

/// How often an event has been detected so far.
#[derive(Debug, Clone, Copy)]
struct Detected {
    count: u32,
    last_ns: i64,
}

/// Settings the gate needs beyond `[gate]`.
#[derive(Debug, Clone)]
pub struct GateSettings {
    /// `[gate]`.
    pub gate: GateConfig,
    /// Days of data a bin needs to count as warm (`cascade.warm_days`).
    pub warm_days: u32,
}

/// The gate of one camera.
pub struct Gate {
    settings: GateSettings,
    zones: Vec<Zone>,
    zone_configs: Vec<ZoneConfig>,
    grid: Option<BlockGrid>,
    next_event_id: u64,
    detected: HashMap<u64, Detected>,
    scratch: Vec<u32>,
}

impl Gate {
    /// A gate over `zones` (empty: one zone covering the whole view).
    pub fn new(settings: GateSettings, zones: Vec<ZoneConfig>) -> Self {
        Gate {
            settings,
            zones: Vec::new(),
            zone_configs: zones,
            grid: None,
            next_event_id: 0,
            detected: HashMap::new(),
            scratch: Vec::new(),
        }
    }

    /// Events started so far.
    pub fn events_started(&self) -> u64 {
        self.next_event_id
    }

    /// Events in progress.
    pub fn open_events(&self) -> usize {
        self.zones
            .iter()
            .flat_map(|z| &z.trackers)
            .filter(|t| t.open().is_some())
            .count()
    }

    fn ensure_zones(&mut self, grid: BlockGrid) {
        if self.grid == Some(grid) {
            return;
        }
        let configs = if self.zone_configs.is_empty() {
            let (w, h) = (grid.frame_width as f64, grid.frame_height as f64);
            vec![ZoneConfig {
                name: "all".into(),
                polygon: vec![[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]],
            }]
        } else {
            self.zone_configs.clone()
        };
        let hold = self.settings.gate.hold_s;
        self.zones = configs
            .into_iter()
            .map(|config| {
                let blocks = grid.blocks_in(&config.polygon);
                if blocks.is_empty() {
                    tracing::warn!(
                        zone = %config.name,
                        "the zone covers no block centre of the {}x{} grid; it will never raise events",
                        grid.grid_w(),
                        grid.grid_h()
                    );
                }
                Zone {
                    config,
                    blocks,
                    trackers: [
                        EventTracker::new(ActivityKind::InPlace, hold),
                        EventTracker::new(ActivityKind::Moving, hold),
                    ],
                }
            })
            .collect();
        self.grid = Some(grid);
    }

    /// Feeds one (validated) activity sample.
    pub fn on_activity(&mut self, h: &ActivityHeader, blocks: &[BlockActivity]) -> Vec<Action> {
        self.ensure_zones(h.block_grid());
        let second = Second {
            start_ns: h.preamble.capture_time_ns - NS_PER_S,
            end_ns: h.preamble.capture_time_ns,
            first_frame: h.first_source_index,
            last_frame: h.last_source_index,
        };
        let origin = h.preamble.origin_wall_ns;
        let warm = h.model_days >= self.settings.warm_days;
        let g = &self.settings.gate;
        let mut actions = Vec::new();
        for zone in &mut self.zones {
            let (mut s1, mut s2, mut mean, mut var) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
            for &i in &zone.blocks {
                let b = &blocks[i as usize];
                if b.s1 >= g.in_place_block_min {
                    s1 += b.s1;
                }
                s2 += b.s2;
                mean += b.lt_mean;
                var += b.lt_sigma * b.lt_sigma;
            }
            let thr = threshold(mean, var, warm, g.k_sigma, g.floor, g.min_threshold);
            for (tracker, value) in zone.trackers.iter_mut().zip([s1, s2]) {
                self.scratch.clear();
                let (pick, min): (fn(&BlockActivity) -> f32, f32) = match tracker.kind() {
                    ActivityKind::InPlace => (|b| b.s1, g.in_place_block_min.max(BLOCK_ACTIVE)),
                    ActivityKind::Moving => (|b| b.s2, BLOCK_ACTIVE),
                };
                self.scratch.extend(
                    zone.blocks
                        .iter()
                        .copied()
                        .filter(|&i| pick(&blocks[i as usize]) >= min),
                );
                let change =
                    tracker.update(second, value, thr, &self.scratch, &mut self.next_event_id);
                match change {
                    Change::None => {}
                    Change::Started(event) => {
                        self.detected.insert(
                            event.id,
                            Detected {
                                count: 0,
                                last_ns: i64::MIN,
                            },
                        );
                        schedule(&mut self.detected, g, &event, second, origin, &mut actions);
                        actions.push(Action::Event {
                            phase: EventPhase::Start,
                            zone: zone.config.name.clone(),
                            event,
                        });
                    }
                    Change::Continued(event) => {
                        schedule(&mut self.detected, g, &event, second, origin, &mut actions);
                    }
                    Change::Ended(event) => {
                        ended(&mut self.detected, &zone.config.name, event, &mut actions);
                    }
                }
            }
        }
        actions
    }

    /// Ends every open event (end of stream).
    pub fn finish(&mut self) -> Vec<Action> {
        let mut actions = Vec::new();
        for zone in &mut self.zones {
            for tracker in &mut zone.trackers {
                if let Some(event) = tracker.finish() {
                    ended(&mut self.detected, &zone.config.name, event, &mut actions);
                }
            }
        }
        actions
    }
}

/// `event` of `zone` ended: no more detection jobs for it, and its end record.
fn ended(
    detected: &mut HashMap<u64, Detected>,
    zone: &str,
    event: Event,
    actions: &mut Vec<Action>,
) {
    detected.remove(&event.id);
    actions.push(Action::Event {
        phase: EventPhase::End,
        zone: zone.to_string(),
        event,
    });
}

/// Adds a detection job for `event` this second if the policy wants one: every
/// `detect_every_s` while it lasts, or else its first `detect_per_event` seconds.
fn schedule(
    detected: &mut HashMap<u64, Detected>,
    g: &GateConfig,
    event: &Event,
    second: Second,
    origin_wall_ns: i64,
    actions: &mut Vec<Action>,
) {
    let Some(d) = detected.get_mut(&event.id) else {
        return;
    };
    let due = match g.detect_every_s {
        Some(every) => d.last_ns == i64::MIN || second.end_ns - d.last_ns >= (every * 1e9) as i64,
        None => d.count < g.detect_per_event,
    };
    if due {
        d.count += 1;
        d.last_ns = second.end_ns;
        // The last frame of the second: its end is exclusive (the next second's
        // first frame is captured exactly at it).
        actions.push(Action::Detect(Job {
            event_id: event.id,
            time_ns: second.end_ns - 1,
            origin_wall_ns,
        }));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_shared::wire::{CameraId, Preamble, Stream};

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
    fn one_detection_per_event_by_default_and_none_without_events() {
        let mut g = gate(GateConfig::default());
        let mut all = Vec::new();
        for s in 0..30 {
            let on = (5..12).contains(&s) || (20..22).contains(&s);
            all.extend(g.on_activity(&header(s, 0), &blocks(if on { 1.0 } else { 0.0 }, 0.0, 0.0)));
        }
        assert_eq!(
            kinds(&all),
            [
                "Detect#0", "Start#0", "End#0", "Detect#1", "Start#1", "End#1"
            ]
        );
        let Action::Event { event, .. } = &all[2] else {
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
                let a = g.on_activity(
                    &header(s, 0),
                    &blocks(if s < 10 { 1.0 } else { 0.0 }, 0.0, 0.0),
                );
                detects += a.iter().filter(|a| matches!(a, Action::Detect(_))).count();
            }
            detects
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

    #[test]
    fn finish_closes_open_events() {
        let mut g = gate(GateConfig::default());
        g.on_activity(&header(0, 0), &blocks(1.0, 0.0, 0.0));
        assert_eq!(g.open_events(), 1);
        assert_eq!(kinds(&g.finish()), ["End#0"]);
        assert_eq!(g.open_events(), 0);
    }
}
