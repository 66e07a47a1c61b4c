//! The gate of one camera: zones, their event trackers, the people the detector
//! confirmed, and the choice of frames to detect. Pure logic over activity samples
//! and detector results; the service wires it to iceoryx2 and the detector thread.
//!
//! **Presence.** A zone's events stay open while its activity is above the
//! threshold (or was, within `hold_s`), while the presence band has a block
//! present in the zone (something that entered stays there, moving or not: the
//! cascade's `presence` module, whose own hold is that a block leaves only once
//! it matched its empty appearance for 2 s; the event lasts at least to the end
//! of every such second, without a further `hold_s`), and while the detector
//! holds a person confirmed there:
//!
//! * a detection creates a confirmed person where a person box overlaps a block
//!   that was active in the detected second (a detector hit on a background that
//!   never moved confirms nobody);
//! * while a zone has confirmed people, the detector runs again on it every
//!   `recheck_s`; a person it no longer finds near where they were (centres
//!   within half a box height) is no longer confirmed;
//! * when a zone's activity falls quiet while its event is open and nobody is
//!   confirmed, one more detection checks whether someone stays there. Events
//!   never wait for the detector: a check that reports after the hold is too
//!   late to keep its event open, but the person it finds is confirmed all the
//!   same (a lossless replay waits for every report before the next second).
//!
//! * a confirmed person under whose box no block was active for
//!   `confirm_still_max_s` is no longer confirmed, whatever the detector finds
//!   (a poster or a mannequin it likes would otherwise stay for ever).
//!
//! So an event ends only when its activity has been quiet for `hold_s`, nothing
//! is present **and** nobody is confirmed in its zone; its end is the latest of
//! its last second above the threshold, its last second with something present
//! and the last frame a person was confirmed in.
//!
//! With `detector.crop` a job searches only [`crop_region`]: around the zone's
//! blocks that move or stay this second and its confirmed people.

use std::collections::HashMap;

use isochron_config::clock::NS_PER_S;
use isochron_config::{GateConfig, ZoneConfig};
use isochron_wire::geometry::BlockGrid;
use isochron_wire::{ActivityHeader, ActivityKind, BlockActivity, Detection, EventPhase};

use crate::events::{Change, Event, EventTracker, Second, threshold};
use crate::worker::{Job, Region};

/// A block counts as involved in an event when its own activity is at least this.
pub const BLOCK_ACTIVE: f32 = 0.01;

/// A block is present when its presence band is at least this.
pub const PRESENT: f32 = 0.5;

/// A detection job the gate has not heard back about for this long (capture
/// time) is forgotten, so a lost report cannot hold events open for ever.
const PENDING_MAX_NS: i64 = 60 * NS_PER_S;

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
    /// Run the detector, then report back with [`Gate::on_detections`].
    Detect(Job),
}

/// A person the detector confirmed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Person {
    /// The latest box, frame pixels: x, y, w, h.
    pub bbox: [f32; 4],
    /// Capture time of the last frame the detector found them in, UTC ns.
    pub seen_ns: i64,
    /// End of the last second in which a block under their box was active, UTC ns.
    pub active_ns: i64,
}

impl Person {
    fn centre(&self) -> (f32, f32) {
        (
            self.bbox[0] + self.bbox[2] / 2.0,
            self.bbox[1] + self.bbox[3] / 2.0,
        )
    }

    /// True if `d` is near enough to be the same person: centres within half
    /// the taller box's height.
    fn near(&self, d: &Detection) -> bool {
        let (cx, cy) = self.centre();
        let (dx, dy) = (d.x + d.w / 2.0 - cx, d.y + d.h / 2.0 - cy);
        let reach = 0.5 * self.bbox[3].max(d.h);
        dx * dx + dy * dy <= reach * reach
    }
}

/// What a finished detection job found.
#[derive(Debug, Clone, Copy)]
pub struct Found<'a> {
    /// Capture time of the detected frame.
    pub capture_time_ns: i64,
    /// Its source index.
    pub source_index: u64,
    /// The boxes found (any class; only people count).
    pub detections: &'a [Detection],
}

struct Zone {
    config: ZoneConfig,
    blocks: Vec<u32>,
    trackers: [EventTracker; 2],
    /// People the detector confirmed in this zone.
    people: Vec<Person>,
    /// When the last re-check of `people` was asked for.
    last_check_ns: i64,
    /// The latest event end a closing check was made for.
    closing_checked: Option<i64>,
}

/// A detection job the gate waits to hear about.
struct Pending {
    zone: usize,
    issued_ns: i64,
    /// The zone's blocks active in the job's second.
    active: Vec<u32>,
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
    next_job_id: u64,
    detected: HashMap<u64, Detected>,
    pending: HashMap<u64, Pending>,
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
            next_job_id: 0,
            detected: HashMap::new(),
            pending: HashMap::new(),
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

    /// People confirmed now, over all zones.
    pub fn confirmed(&self) -> usize {
        self.zones.iter().map(|z| z.people.len()).sum()
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
                    people: Vec::new(),
                    last_check_ns: i64::MIN,
                    closing_checked: None,
                }
            })
            .collect();
        self.pending.clear();
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
        // Reports that never came (they should) hold nothing open for ever.
        self.pending
            .retain(|_, p| second.end_ns - p.issued_ns < PENDING_MAX_NS);
        let warm = h.model_days >= self.settings.warm_days;
        let g = &self.settings.gate;
        let recheck_ns = (g.recheck_s * 1e9) as i64;
        let still_max_ns = (g.confirm_still_max_s * 1e9) as i64;
        let crop_margin = g.detector.crop.then_some(g.detector.crop_margin_px);
        let grid = h.block_grid();
        let mut actions = Vec::new();
        for (zi, zone) in self.zones.iter_mut().enumerate() {
            // A person nothing moved under for `confirm_still_max_s` is no longer
            // confirmed, whatever the detector says (a poster, a mannequin).
            zone.people.retain_mut(|p| {
                if blocks_under(&grid, &p.bbox).any(|i| {
                    blocks
                        .get(i as usize)
                        .is_some_and(|b| b.s1 >= BLOCK_ACTIVE || b.s2 >= BLOCK_ACTIVE)
                }) {
                    p.active_ns = second.end_ns;
                }
                let keep = second.end_ns - p.active_ns < still_max_ns;
                if !keep {
                    tracing::info!(
                        zone = %zone.config.name,
                        "a confirmed person has not moved for {} s: no longer confirmed",
                        g.confirm_still_max_s
                    );
                }
                keep
            });
            let (mut s1, mut s2, mut mean, mut var) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
            let mut present = false;
            for &i in &zone.blocks {
                let b = &blocks[i as usize];
                present |= b.present >= PRESENT;
                if b.s1 >= g.in_place_block_min {
                    s1 += b.s1;
                }
                s2 += b.s2;
                mean += b.lt_mean;
                var += b.lt_sigma * b.lt_sigma;
            }
            let thr = threshold(mean, var, warm, g.k_sigma, g.floor, g.min_threshold);
            let hold_open = !zone.people.is_empty() || present;
            let mut quiet = true;
            let mut wanted = None;
            let zone_actions = actions.len();
            for (tracker, value) in zone.trackers.iter_mut().zip([s1, s2]) {
                quiet &= value <= thr;
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
                let change = tracker.update(
                    second,
                    value,
                    thr,
                    &self.scratch,
                    &mut self.next_event_id,
                    hold_open,
                );
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
                        if schedule(&mut self.detected, g, &event, second) {
                            wanted.get_or_insert(event.id);
                        }
                        actions.push(Action::Event {
                            phase: EventPhase::Start,
                            zone: zone.config.name.clone(),
                            event,
                        });
                    }
                    Change::Continued(event) => {
                        if schedule(&mut self.detected, g, &event, second) {
                            wanted.get_or_insert(event.id);
                        }
                    }
                    Change::Ended(event) => {
                        ended(&mut self.detected, &zone.config.name, event, &mut actions);
                    }
                }
            }
            // Something stays in the zone (the presence band): its events last at
            // least to the end of this second, and end once nothing is present and
            // the activity has been quiet for the hold.
            if present {
                for tracker in &mut zone.trackers {
                    tracker.cover(second);
                }
            }
            // Presence: re-check confirmed people, or check once whether someone
            // stays where the activity fell quiet. At most one detection per zone
            // and second, whoever asks for it; each counts as a check.
            let open = zone
                .trackers
                .iter()
                .filter_map(|t| t.open())
                .max_by_key(|e| e.end_ns);
            let idle = !self.pending.values().any(|p| p.zone == zi);
            let recheck = idle
                && !zone.people.is_empty()
                && second.end_ns.saturating_sub(zone.last_check_ns) >= recheck_ns;
            let closing = idle
                && zone.people.is_empty()
                && quiet
                && !present
                && open.is_some_and(|e| zone.closing_checked != Some(e.end_ns));
            if closing {
                zone.closing_checked = open.map(|e| e.end_ns);
            }
            if g.detector.enabled && (wanted.is_some() || recheck || closing) {
                zone.last_check_ns = second.end_ns;
                let event_id = wanted.or(open.map(|e| e.id)).unwrap_or(u64::MAX);
                let job = issue(
                    &mut self.pending,
                    &mut self.next_job_id,
                    (zi, &zone.blocks, blocks),
                    event_id,
                    second,
                    h.preamble.origin_wall_ns,
                );
                // The crop: where something moves now or stays (not the slow S1
                // tails of earlier passers-by), and the people confirmed.
                let region = crop_margin.map_or(Region::WHOLE, |margin| {
                    self.scratch.clear();
                    self.scratch
                        .extend(zone.blocks.iter().copied().filter(|&i| {
                            let b = &blocks[i as usize];
                            b.s2 >= BLOCK_ACTIVE || b.s1 >= g.in_place_block_min.max(BLOCK_ACTIVE)
                        }));
                    crop_region(&grid, &self.scratch, &zone.people, margin)
                });
                let job = Job { region, ..job };
                // Before the zone's event records: the job names the event.
                actions.insert(zone_actions, Action::Detect(job));
            }
        }
        actions
    }

    /// What detection job `job_id` found; `None` if it did not run (dropped, its
    /// frame gone, the detector failed). Updates the confirmed people of its
    /// zone: those it searched for and no longer finds near where they were are
    /// no longer confirmed; people it finds on blocks active in its second are.
    pub fn on_detections(&mut self, job_id: u64, region: Region, found: Option<Found<'_>>) {
        let Some(pending) = self.pending.remove(&job_id) else {
            return;
        };
        let (Some(zone), Some(grid)) = (self.zones.get_mut(pending.zone), self.grid) else {
            return;
        };
        let Some(found) = found else {
            // Not run: a re-check is due again at once.
            if !zone.people.is_empty() {
                zone.last_check_ns = i64::MIN;
            }
            return;
        };
        let t = found.capture_time_ns;
        let in_zone = |d: &&Detection| {
            d.class == 0
                && d.w > 0.0
                && d.h > 0.0
                && block_at(&grid, d.x + d.w / 2.0, d.y + d.h)
                    .is_some_and(|b| zone.blocks.binary_search(&b).is_ok())
        };
        let people: Vec<&Detection> = found.detections.iter().filter(in_zone).collect();
        zone.people.retain_mut(|person| {
            let (cx, cy) = person.centre();
            if !region.contains(cx, cy) {
                return true; // not searched this time
            }
            match people.iter().find(|d| person.near(d)) {
                Some(d) => {
                    person.bbox = [d.x, d.y, d.w, d.h];
                    person.seen_ns = person.seen_ns.max(t);
                    true
                }
                None => false,
            }
        });
        for d in people {
            let known = zone.people.iter().any(|p| p.near(d));
            if !known && overlaps_blocks(&grid, &pending.active, d) {
                if zone.people.is_empty() {
                    zone.last_check_ns = t; // the next check is a re-check away
                }
                zone.people.push(Person {
                    bbox: [d.x, d.y, d.w, d.h],
                    seen_ns: t,
                    active_ns: t,
                });
            }
        }
        if zone.people.iter().any(|p| p.seen_ns == t) {
            for tracker in &mut zone.trackers {
                tracker.extend(t, found.source_index);
            }
        }
    }

    /// Ends every open event (end of stream).
    pub fn finish(&mut self) -> Vec<Action> {
        let mut actions = Vec::new();
        self.pending.clear();
        for zone in &mut self.zones {
            zone.people.clear();
            for tracker in &mut zone.trackers {
                if let Some(event) = tracker.finish() {
                    ended(&mut self.detected, &zone.config.name, event, &mut actions);
                }
            }
        }
        actions
    }
}

/// A detection job on the last frame of `second` (published by capture at
/// `origin_wall_ns`) for `event_id`, in zone `zi` (its `zone_blocks`, of the
/// sample's `blocks`), remembered until its report.
fn issue(
    pending: &mut HashMap<u64, Pending>,
    next_job_id: &mut u64,
    (zi, zone_blocks, blocks): (usize, &[u32], &[BlockActivity]),
    event_id: u64,
    second: Second,
    origin_wall_ns: i64,
) -> Job {
    let active = zone_blocks
        .iter()
        .copied()
        .filter(|&i| {
            let b = &blocks[i as usize];
            b.s1 >= BLOCK_ACTIVE || b.s2 >= BLOCK_ACTIVE
        })
        .collect();
    let id = *next_job_id;
    *next_job_id += 1;
    pending.insert(
        id,
        Pending {
            zone: zi,
            issued_ns: second.end_ns,
            active,
        },
    );
    // The last frame of the second: its end is exclusive (the next second's
    // first frame is captured exactly at it).
    Job {
        id,
        event_id,
        time_ns: second.end_ns - 1,
        region: Region::WHOLE,
        origin_wall_ns,
    }
}

/// The region to search around `active` blocks and confirmed `people`, `margin`
/// pixels more on each side, clamped to the frame; the whole frame when there
/// is nothing to search around or the crop would cover it all.
pub fn crop_region(grid: &BlockGrid, active: &[u32], people: &[Person], margin: u32) -> Region {
    let (w, px) = (grid.grid_w(), grid.block_px);
    let blocks = active.iter().map(|&i| {
        let (x, y) = ((i % w) * px, (i / w) * px);
        [x, y, x + px, y + px]
    });
    let boxes = people.iter().map(|p| {
        let [x, y, bw, bh] = p.bbox;
        [
            x.max(0.0) as u32,
            y.max(0.0) as u32,
            (x + bw).max(0.0).ceil() as u32,
            (y + bh).max(0.0).ceil() as u32,
        ]
    });
    let Some([x0, y0, x1, y1]) = blocks.chain(boxes).reduce(|a, b| {
        [
            a[0].min(b[0]),
            a[1].min(b[1]),
            a[2].max(b[2]),
            a[3].max(b[3]),
        ]
    }) else {
        return Region::WHOLE;
    };
    let (fw, fh) = (grid.frame_width, grid.frame_height);
    let (x0, y0) = (x0.saturating_sub(margin), y0.saturating_sub(margin));
    let (x1, y1) = (
        x1.saturating_add(margin).min(fw),
        y1.saturating_add(margin).min(fh),
    );
    if x0 >= x1 || y0 >= y1 || (x0 == 0 && y0 == 0 && x1 == fw && y1 == fh) {
        return Region::WHOLE;
    }
    Region {
        x: x0,
        y: y0,
        w: x1 - x0,
        h: y1 - y0,
    }
}

/// The blocks (row-major indices) a frame box `[x, y, w, h]` overlaps.
fn blocks_under(grid: &BlockGrid, bbox: &[f32; 4]) -> impl Iterator<Item = u32> + use<> {
    let (gw, gh, px) = (grid.grid_w(), grid.grid_h(), grid.block_px as f32);
    let [x, y, w, h] = *bbox;
    let col = move |v: f32, n: u32| ((v / px).floor().max(0.0) as u32).min(n);
    let (c0, c1) = (col(x, gw), col((x + w - 0.01).max(x), gw - 1) + 1);
    let (r0, r1) = (col(y, gh), col((y + h - 0.01).max(y), gh - 1) + 1);
    (r0..r1).flat_map(move |r| (c0..c1).map(move |c| r * gw + c))
}

/// The block (row-major index) under the frame point `(x, y)`, if inside.
fn block_at(grid: &BlockGrid, x: f32, y: f32) -> Option<u32> {
    // Feet on the bottom edge belong to the last row.
    let (x, y) = (x.floor(), y.floor().min(grid.frame_height as f32 - 1.0));
    if x < 0.0 || y < 0.0 || x >= grid.frame_width as f32 {
        return None;
    }
    let (bx, by) = (x as u32 / grid.block_px, y as u32 / grid.block_px);
    Some(by * grid.grid_w() + bx)
}

/// True if the box `d` overlaps one of `blocks`.
fn overlaps_blocks(grid: &BlockGrid, blocks: &[u32], d: &Detection) -> bool {
    let (w, px) = (grid.grid_w(), grid.block_px as f32);
    blocks.iter().any(|&i| {
        let (x0, y0) = ((i % w) as f32 * px, (i / w) as f32 * px);
        d.x < x0 + px && d.x + d.w > x0 && d.y < y0 + px && d.y + d.h > y0
    })
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

/// True if `event` is due a detection this second by the policy: every
/// `detect_every_s` while it lasts, or else its first `detect_per_event` seconds.
fn schedule(
    detected: &mut HashMap<u64, Detected>,
    g: &GateConfig,
    event: &Event,
    second: Second,
) -> bool {
    let Some(d) = detected.get_mut(&event.id) else {
        return false;
    };
    let due = match g.detect_every_s {
        Some(every) => d.last_ns == i64::MIN || second.end_ns - d.last_ns >= (every * 1e9) as i64,
        None => d.count < g.detect_per_event,
    };
    if due {
        d.count += 1;
        d.last_ns = second.end_ns;
    }
    due
}

#[cfg(test)]
mod tests {
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
                "Detect#0", "Start#0", "Detect#0", "End#0", "Detect#1", "Start#1", "Detect#1",
                "End#1"
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
}
