//! Event detection with hysteresis, for one zone and one kind of activity.
//!
//! Each activity second the tracker gets the zone's activity sum and the threshold
//! in force. Above it, an event starts (or continues, raising its peak); below it
//! for `hold` after the last second above, the event ends — unless the caller
//! holds it open (someone is still confirmed there). The event spans from the
//! start of its first second above the threshold to the end of its last, or to the
//! last frame a person was confirmed in ([`EventTracker::extend`]), whichever is
//! later.

use isochron_wire::ActivityKind;

/// One second of activity, as the cascade reported it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Second {
    /// Start of the second, UTC ns.
    pub start_ns: i64,
    /// End of the second (the activity sample's capture time), UTC ns.
    pub end_ns: i64,
    /// Source index of its first frame.
    pub first_frame: u64,
    /// Source index of its last frame.
    pub last_frame: u64,
}

/// The threshold a zone's activity sum must exceed.
pub fn threshold(
    lt_mean_sum: f32,
    lt_var_sum: f32,
    warm: bool,
    k_sigma: f32,
    floor: f32,
    min_threshold: f32,
) -> f32 {
    if warm {
        (lt_mean_sum + k_sigma * lt_var_sum.max(0.0).sqrt()).max(min_threshold)
    } else {
        floor
    }
}

/// An event in progress or finished.
#[derive(Debug, Clone, PartialEq)]
pub struct Event {
    /// Per-camera event number.
    pub id: u64,
    /// Kind of activity.
    pub kind: ActivityKind,
    /// Start, UTC ns.
    pub start_ns: i64,
    /// Source index of the first frame.
    pub start_frame: u64,
    /// End of the last second above the threshold, UTC ns.
    pub end_ns: i64,
    /// Source index of the last frame of that second.
    pub end_frame: u64,
    /// Highest activity sum seen.
    pub peak: f32,
    /// Threshold when the event started.
    pub threshold: f32,
    /// Blocks (row-major indices) that were active during the event, sorted.
    pub blocks: Vec<u32>,
}

/// What an update did.
#[derive(Debug, Clone, PartialEq)]
pub enum Change {
    /// Nothing to report.
    None,
    /// An event started (a copy of its state).
    Started(Event),
    /// The open event is still above its threshold this second.
    Continued(Event),
    /// An event ended.
    Ended(Event),
}

/// Tracks events of one kind in one zone.
#[derive(Debug, Clone)]
pub struct EventTracker {
    kind: ActivityKind,
    hold_ns: i64,
    open: Option<Event>,
    /// The open event ends `hold_ns` after this: its last second above the
    /// threshold, or the last frame a person was confirmed in.
    hold_from_ns: i64,
}

impl EventTracker {
    /// A tracker for `kind` that ends events after `hold_s` below threshold.
    pub fn new(kind: ActivityKind, hold_s: f64) -> Self {
        EventTracker {
            kind,
            hold_ns: (hold_s * 1e9) as i64,
            open: None,
            hold_from_ns: i64::MIN,
        }
    }

    /// The kind of activity this tracker watches.
    pub fn kind(&self) -> ActivityKind {
        self.kind
    }

    /// The event in progress, if any.
    pub fn open(&self) -> Option<&Event> {
        self.open.as_ref()
    }

    /// Feeds one second: the zone's activity sum `value`, the `threshold` in force,
    /// and the blocks active this second. `next_id` numbers new events. With
    /// `hold_open`, an open event does not end however long it stays below.
    pub fn update(
        &mut self,
        second: Second,
        value: f32,
        threshold: f32,
        active_blocks: &[u32],
        next_id: &mut u64,
        hold_open: bool,
    ) -> Change {
        let above = value > threshold;
        match (&mut self.open, above) {
            (None, false) => Change::None,
            (None, true) => {
                let event = Event {
                    id: *next_id,
                    kind: self.kind,
                    start_ns: second.start_ns,
                    start_frame: second.first_frame,
                    end_ns: second.end_ns,
                    end_frame: second.last_frame,
                    peak: value,
                    threshold,
                    blocks: active_blocks.to_vec(),
                };
                *next_id += 1;
                self.open = Some(event.clone());
                self.hold_from_ns = second.end_ns;
                Change::Started(event)
            }
            (Some(event), true) => {
                event.end_ns = second.end_ns;
                event.end_frame = second.last_frame;
                self.hold_from_ns = second.end_ns;
                event.peak = event.peak.max(value);
                merge_sorted(&mut event.blocks, active_blocks);
                Change::Continued(event.clone())
            }
            (Some(_), false) => {
                if !hold_open && second.end_ns - self.hold_from_ns >= self.hold_ns {
                    Change::Ended(self.open.take().expect("open event"))
                } else {
                    Change::None
                }
            }
        }
    }

    /// Someone was seen at `time_ns` (frame `frame`): the open event, if any, lasts
    /// at least until then, and its hold runs from then.
    pub fn extend(&mut self, time_ns: i64, frame: u64) {
        if let Some(event) = &mut self.open
            && time_ns > event.end_ns
        {
            event.end_ns = time_ns;
            event.end_frame = event.end_frame.max(frame);
            self.hold_from_ns = self.hold_from_ns.max(time_ns);
        }
    }

    /// Something stayed present through `second` (the presence band, which has
    /// a hold of its own): the open event, if any, spans it; its hold still runs
    /// from its last second above the threshold.
    pub fn cover(&mut self, second: Second) {
        if let Some(event) = &mut self.open
            && second.end_ns > event.end_ns
        {
            event.end_ns = second.end_ns;
            event.end_frame = event.end_frame.max(second.last_frame);
        }
    }

    /// Ends the open event now (end of stream).
    pub fn finish(&mut self) -> Option<Event> {
        self.open.take()
    }
}

/// Merges sorted `add` into sorted `into`, without duplicates.
fn merge_sorted(into: &mut Vec<u32>, add: &[u32]) {
    if add.iter().all(|b| into.binary_search(b).is_ok()) {
        return;
    }
    into.extend_from_slice(add);
    into.sort_unstable();
    into.dedup();
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: i64 = 1_000_000_000;

    fn second(i: i64) -> Second {
        Second {
            start_ns: i * S,
            end_ns: (i + 1) * S,
            first_frame: (i * 10) as u64,
            last_frame: (i * 10 + 9) as u64,
        }
    }

    /// Runs `values` (one per second) through a tracker with threshold 1, hold 3 s.
    fn run(values: &[f32]) -> Vec<(i64, Change)> {
        let mut t = EventTracker::new(ActivityKind::Moving, 3.0);
        let mut id = 0;
        values
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                (
                    i as i64,
                    t.update(second(i as i64), v, 1.0, &[i as u32], &mut id, false),
                )
            })
            .filter(|(_, c)| !matches!(c, Change::None | Change::Continued(_)))
            .collect()
    }

    #[test]
    fn starts_above_and_ends_after_the_hold() {
        let changes = run(&[0.0, 0.5, 2.0, 3.0, 0.2, 0.1, 0.1, 0.0, 0.0]);
        assert_eq!(changes.len(), 2, "{changes:?}");
        let Change::Started(start) = &changes[0].1 else {
            panic!()
        };
        assert_eq!(changes[0].0, 2);
        assert_eq!((start.start_ns, start.start_frame), (2 * S, 20));
        // Below from second 4; the hold of 3 s after the end of second 3 (4 s)
        // expires at the end of second 6 (7 s).
        let Change::Ended(end) = &changes[1].1 else {
            panic!()
        };
        assert_eq!(changes[1].0, 6);
        assert_eq!((end.end_ns, end.end_frame), (4 * S, 39));
        assert_eq!(end.peak, 3.0);
        assert_eq!(end.blocks, vec![2, 3]);
    }

    #[test]
    fn dips_shorter_than_the_hold_do_not_split_an_event() {
        let changes = run(&[2.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0]);
        assert_eq!(changes.len(), 2, "one event: {changes:?}");
        let Change::Ended(end) = &changes[1].1 else {
            panic!()
        };
        assert_eq!((end.start_ns, end.end_ns), (0, 4 * S));
    }

    #[test]
    fn the_threshold_is_a_floor_when_cold_and_k_sigma_when_warm() {
        assert_eq!(threshold(0.3, 0.04, false, 3.0, 0.5, 0.2), 0.5);
        assert!((threshold(0.3, 0.04, true, 3.0, 0.5, 0.2) - 0.9).abs() < 1e-6);
        // A quiet warm minute: sigma 0 → never below the minimum.
        assert_eq!(threshold(0.0, 0.0, true, 3.0, 0.5, 0.2), 0.2);
    }

    #[test]
    fn a_held_event_outlasts_the_hold_and_ends_after_its_last_sighting() {
        let mut t = EventTracker::new(ActivityKind::Moving, 3.0);
        let mut id = 0;
        assert!(matches!(
            t.update(second(0), 2.0, 1.0, &[], &mut id, false),
            Change::Started(_)
        ));
        // Quiet for 20 s, but held open: someone is still confirmed there.
        for i in 1..20 {
            assert_eq!(
                t.update(second(i), 0.0, 1.0, &[], &mut id, true),
                Change::None
            );
        }
        t.extend(15 * S, 155);
        // Released: it ends once the hold has passed since the last sighting.
        assert_eq!(
            t.update(second(16), 0.0, 1.0, &[], &mut id, false),
            Change::None
        );
        let Change::Ended(end) = t.update(second(17), 0.0, 1.0, &[], &mut id, false) else {
            panic!("ends 3 s after 15 s")
        };
        assert_eq!((end.start_ns, end.end_ns, end.end_frame), (0, 15 * S, 155));
    }

    #[test]
    fn values_at_the_threshold_do_not_start_events() {
        assert!(run(&[1.0, 1.0, 1.0]).is_empty());
    }
}
