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

use crate::detector::Region;
use crate::events::{Change, Event, EventTracker, Second, threshold};
use crate::people::{block_at, blocks_under, overlaps_blocks};
use crate::worker::Job;

pub use crate::people::{Person, crop_region};

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

impl Zone {
    /// Forgets a person nothing moved under for `still_max_s`, whatever the
    /// detector says (a poster, a mannequin).
    fn forget_still_people(&mut self, t: &Tick<'_>, still_max_s: f64) {
        let still_max_ns = (still_max_s * 1e9) as i64;
        let name = &self.config.name;
        self.people.retain_mut(|p| {
            if blocks_under(&t.grid, &p.bbox).any(|i| {
                t.blocks
                    .get(i as usize)
                    .is_some_and(|b| b.s1 >= BLOCK_ACTIVE || b.s2 >= BLOCK_ACTIVE)
            }) {
                p.active_ns = t.second.end_ns;
            }
            let keep = t.second.end_ns - p.active_ns < still_max_ns;
            if !keep {
                tracing::info!(
                    zone = %name,
                    "a confirmed person has not moved for {still_max_s} s: no longer confirmed"
                );
            }
            keep
        });
    }
}

/// One activity sample as the zones see it.
struct Tick<'a> {
    /// The second it covers.
    second: Second,
    /// Its blocks.
    blocks: &'a [BlockActivity],
    /// Its block grid.
    grid: BlockGrid,
    /// Whether the long-term model has enough days at this t*.
    warm: bool,
    /// When capture published its last frame (wall clock, UTC ns).
    origin_wall_ns: i64,
}

/// A zone's activity in one second, summed over its blocks.
struct ZoneSums {
    /// In-place activity of the blocks at or above `in_place_block_min`.
    s1: f32,
    /// Moving activity.
    s2: f32,
    /// Long-term mean at t*.
    mean: f32,
    /// Long-term variance at t*.
    var: f32,
    /// Whether a block of the zone is present (the presence band).
    present: bool,
}

impl ZoneSums {
    /// The sums over `zone`'s blocks of `blocks`.
    fn of(zone: &Zone, blocks: &[BlockActivity], in_place_block_min: f32) -> ZoneSums {
        let mut sums = ZoneSums {
            s1: 0.0,
            s2: 0.0,
            mean: 0.0,
            var: 0.0,
            present: false,
        };
        for &i in &zone.blocks {
            let b = &blocks[i as usize];
            sums.present |= b.present >= PRESENT;
            if b.s1 >= in_place_block_min {
                sums.s1 += b.s1;
            }
            sums.s2 += b.s2;
            sums.mean += b.lt_mean;
            sums.var += b.lt_sigma * b.lt_sigma;
        }
        sums
    }
}

/// What a zone's second asks of the detector.
#[derive(Debug, Clone, Copy)]
struct Asks {
    /// The event its policy wants detected, if any.
    wanted: Option<u64>,
    /// Both sums at or below the threshold.
    quiet: bool,
    /// Something is present in the zone.
    present: bool,
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
        let tick = Tick {
            second: Second {
                start_ns: h.preamble.capture_time_ns - NS_PER_S,
                end_ns: h.preamble.capture_time_ns,
                first_frame: h.first_source_index,
                last_frame: h.last_source_index,
            },
            blocks,
            grid: h.block_grid(),
            warm: h.model_days >= self.settings.warm_days,
            origin_wall_ns: h.preamble.origin_wall_ns,
        };
        // Reports that never came (they should) hold nothing open for ever.
        self.pending
            .retain(|_, p| tick.second.end_ns - p.issued_ns < PENDING_MAX_NS);
        let mut actions = Vec::new();
        let mut zones = std::mem::take(&mut self.zones);
        for (zi, zone) in zones.iter_mut().enumerate() {
            self.zone_second(zi, zone, &tick, &mut actions);
        }
        self.zones = zones;
        actions
    }

    /// Zone `zi`'s part of an activity sample: its confirmed people, its event
    /// trackers, and a detection job if one is due.
    fn zone_second(&mut self, zi: usize, zone: &mut Zone, t: &Tick<'_>, actions: &mut Vec<Action>) {
        let g = &self.settings.gate;
        zone.forget_still_people(t, g.confirm_still_max_s);
        let sums = ZoneSums::of(zone, t.blocks, g.in_place_block_min);
        let thr = threshold(
            sums.mean,
            sums.var,
            t.warm,
            g.k_sigma,
            g.floor,
            g.min_threshold,
        );
        let zone_actions = actions.len();
        let hold_open = !zone.people.is_empty() || sums.present;
        let (wanted, quiet) =
            self.track_events(zone, t, [sums.s1, sums.s2], (thr, hold_open), actions);
        // Something stays in the zone (the presence band): its events last at
        // least to the end of this second, and end once nothing is present and
        // the activity has been quiet for the hold.
        if sums.present {
            for tracker in &mut zone.trackers {
                tracker.cover(t.second);
            }
        }
        let asks = Asks {
            wanted,
            quiet,
            present: sums.present,
        };
        if let Some(job) = self.detection_job(zi, zone, t, asks) {
            // Before the zone's event records: the job names the event.
            actions.insert(zone_actions, Action::Detect(job));
        }
    }

    /// Feeds the zone's in-place and moving sums (`values`) to its trackers with
    /// threshold `thr` (events held open if `hold_open`); pushes the event records.
    /// Returns the event due a detection this second, if any, and whether both sums
    /// are quiet (at or below the threshold).
    fn track_events(
        &mut self,
        zone: &mut Zone,
        t: &Tick<'_>,
        values: [f32; 2],
        (thr, hold_open): (f32, bool),
        actions: &mut Vec<Action>,
    ) -> (Option<u64>, bool) {
        let g = &self.settings.gate;
        let mut quiet = true;
        let mut wanted = None;
        for (tracker, value) in zone.trackers.iter_mut().zip(values) {
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
                    .filter(|&i| pick(&t.blocks[i as usize]) >= min),
            );
            let change = tracker.update(
                t.second,
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
                    if schedule(&mut self.detected, g, &event, t.second) {
                        wanted.get_or_insert(event.id);
                    }
                    actions.push(Action::Event {
                        phase: EventPhase::Start,
                        zone: zone.config.name.clone(),
                        event,
                    });
                }
                Change::Continued(event) => {
                    if schedule(&mut self.detected, g, &event, t.second) {
                        wanted.get_or_insert(event.id);
                    }
                }
                Change::Ended(event) => {
                    ended(&mut self.detected, &zone.config.name, event, actions);
                }
            }
        }
        (wanted, quiet)
    }

    /// The detection job zone `zi` is due this second, if any: one its events'
    /// policy wants (`asks.wanted`), or for presence — a re-check of confirmed
    /// people, or one check whether someone stays where the activity fell quiet. At
    /// most one detection per zone and second, whoever asks for it; each counts as
    /// a check.
    fn detection_job(
        &mut self,
        zi: usize,
        zone: &mut Zone,
        t: &Tick<'_>,
        asks: Asks,
    ) -> Option<Job> {
        let g = &self.settings.gate;
        let recheck_ns = (g.recheck_s * 1e9) as i64;
        let open = zone
            .trackers
            .iter()
            .filter_map(|t| t.open())
            .max_by_key(|e| e.end_ns);
        let idle = !self.pending.values().any(|p| p.zone == zi);
        let recheck = idle
            && !zone.people.is_empty()
            && t.second.end_ns.saturating_sub(zone.last_check_ns) >= recheck_ns;
        let closing = idle
            && zone.people.is_empty()
            && asks.quiet
            && !asks.present
            && open.is_some_and(|e| zone.closing_checked != Some(e.end_ns));
        if closing {
            zone.closing_checked = open.map(|e| e.end_ns);
        }
        if !(g.detector.enabled && (asks.wanted.is_some() || recheck || closing)) {
            return None;
        }
        zone.last_check_ns = t.second.end_ns;
        let event_id = asks.wanted.or(open.map(|e| e.id)).unwrap_or(u64::MAX);
        let job = issue(
            &mut self.pending,
            &mut self.next_job_id,
            (zi, &zone.blocks, t.blocks),
            event_id,
            t.second,
            t.origin_wall_ns,
        );
        // The crop: where something moves now or stays (not the slow S1
        // tails of earlier passers-by), and the people confirmed.
        let crop_margin = g.detector.crop.then_some(g.detector.crop_margin_px);
        let region = crop_margin.map_or(Region::WHOLE, |margin| {
            self.scratch.clear();
            self.scratch
                .extend(zone.blocks.iter().copied().filter(|&i| {
                    let b = &t.blocks[i as usize];
                    b.s2 >= BLOCK_ACTIVE || b.s1 >= g.in_place_block_min.max(BLOCK_ACTIVE)
                }));
            crop_region(&t.grid, &self.scratch, &zone.people, margin)
        });
        Some(Job { region, ..job })
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
mod tests;
