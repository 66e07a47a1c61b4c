//! People counted from tracks: per zone, who is in it now, the Δt-weighted mean
//! and the peak of each minute, and each visit's dwell; per line, each track's
//! crossings in and out.
//!
//! Zones and lines are on the tracks' plane (the caller maps the config's frame
//! pixels through the camera's homography, which keeps straight edges
//! straight). A track is in a zone while its position is inside the polygon
//! (even-odd rule); it crosses a line when the segment between two of its
//! positions crosses one of the line's segments, `in` being the side the
//! config names.

use std::collections::{BTreeMap, BTreeSet};

/// Which side of a line's direction (first point to last) is "in".
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// Left of the direction, as a walker along it sees it (y down, image
    /// convention: counter-clockwise on the page is left).
    Left,
    /// Right of it.
    Right,
}

/// A crossing's direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Onto the `in` side.
    In,
    /// Off it.
    Out,
}

impl Direction {
    /// `in` or `out`, as files and topics say.
    pub fn name(self) -> &'static str {
        match self {
            Direction::In => "in",
            Direction::Out => "out",
        }
    }
}

/// What the counter saw happen.
#[derive(Debug, Clone, PartialEq)]
pub enum Happened {
    /// A track entered a zone.
    Entered {
        /// The zone (index).
        zone: usize,
        /// The track.
        track: u64,
        /// When, ns.
        t_ns: i64,
    },
    /// A track left a zone (or ended in it).
    Left {
        /// The zone (index).
        zone: usize,
        /// The track.
        track: u64,
        /// When it entered, ns.
        entered_ns: i64,
        /// When it left, ns.
        t_ns: i64,
        /// Seconds it was inside.
        dwell_s: f64,
    },
    /// A track crossed a line.
    Crossed {
        /// The line (index).
        line: usize,
        /// The track.
        track: u64,
        /// When (the observation after the crossing), ns.
        t_ns: i64,
        /// Onto the line's `in` side, or off it.
        direction: Direction,
    },
}

/// One zone's minute: the Δt-weighted mean of people in it and the peak.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MinuteOccupancy {
    /// The minute, minutes since the Unix epoch.
    pub minute: i64,
    /// People, averaged over the minute's observed time.
    pub mean: f64,
    /// The most at once.
    pub peak: usize,
}

#[derive(Debug, Clone, Default)]
struct ZoneState {
    /// Track → when it entered.
    inside: BTreeMap<u64, i64>,
    weighted: f64,
    observed_s: f64,
    peak: usize,
}

/// Counts of one camera's zones and lines.
#[derive(Debug, Clone)]
pub struct Counter {
    zones: Vec<Vec<[f64; 2]>>,
    lines: Vec<(Vec<[f64; 2]>, Side)>,
    state: Vec<ZoneState>,
    /// Track → its last position and time.
    last: BTreeMap<u64, ([f64; 2], i64)>,
    last_ns: Option<i64>,
    done_minutes: Vec<(usize, MinuteOccupancy)>,
}

impl Counter {
    /// A counter of `zones` (polygons, at least 3 points) and `lines`
    /// (polylines, at least 2 points, and their `in` side).
    pub fn new(zones: Vec<Vec<[f64; 2]>>, lines: Vec<(Vec<[f64; 2]>, Side)>) -> Self {
        let state = vec![ZoneState::default(); zones.len()];
        Counter {
            zones,
            lines,
            state,
            last: BTreeMap::new(),
            last_ns: None,
            done_minutes: Vec::new(),
        }
    }

    /// People in zone `zone` now.
    pub fn people(&self, zone: usize) -> usize {
        self.state.get(zone).map_or(0, |z| z.inside.len())
    }

    /// Takes where every live track is at `t_ns` (`positions`: track id and
    /// position; a track absent from it is gone); returns what happened.
    pub fn observe(&mut self, t_ns: i64, positions: &[(u64, [f64; 2])]) -> Vec<Happened> {
        let mut happened = Vec::new();
        self.accumulate(t_ns);
        for &(track, at) in positions {
            if let Some(&(from, _)) = self.last.get(&track) {
                self.crossings(track, from, at, t_ns, &mut happened);
            }
            self.last.insert(track, (at, t_ns));
        }
        let live: BTreeSet<u64> = positions.iter().map(|(id, _)| *id).collect();
        self.last.retain(|id, _| live.contains(id));
        for (z, polygon) in self.zones.iter().enumerate() {
            let state = &mut self.state[z];
            for &(track, at) in positions {
                if inside(polygon, at) && !state.inside.contains_key(&track) {
                    state.inside.insert(track, t_ns);
                    happened.push(Happened::Entered {
                        zone: z,
                        track,
                        t_ns,
                    });
                }
            }
            let left: Vec<(u64, i64)> = state
                .inside
                .iter()
                .filter(|(id, _)| {
                    !positions
                        .iter()
                        .any(|(track, at)| track == *id && inside(polygon, *at))
                })
                .map(|(id, entered)| (*id, *entered))
                .collect();
            for (track, entered_ns) in left {
                state.inside.remove(&track);
                happened.push(Happened::Left {
                    zone: z,
                    track,
                    entered_ns,
                    t_ns,
                    dwell_s: (t_ns - entered_ns) as f64 / 1e9,
                });
            }
            state.peak = state.peak.max(state.inside.len());
        }
        happened
    }

    /// The minutes completed since the last call: (zone index, occupancy).
    pub fn take_minutes(&mut self) -> Vec<(usize, MinuteOccupancy)> {
        std::mem::take(&mut self.done_minutes)
    }

    /// Adds the time since the last observation, at the occupancy it had, to
    /// each zone's minute, completing minutes as `t_ns` passes them.
    fn accumulate(&mut self, t_ns: i64) {
        const MINUTE: i64 = 60_000_000_000;
        let Some(mut from) = self.last_ns.replace(t_ns.max(self.last_ns.unwrap_or(t_ns))) else {
            return;
        };
        while from < t_ns {
            let minute = from.div_euclid(MINUTE);
            let until = ((minute + 1) * MINUTE).min(t_ns);
            let dt = (until - from) as f64 / 1e9;
            for (z, state) in self.state.iter_mut().enumerate() {
                let people = state.inside.len();
                state.weighted += people as f64 * dt;
                state.observed_s += dt;
                state.peak = state.peak.max(people);
                if until == (minute + 1) * MINUTE {
                    self.done_minutes.push((
                        z,
                        MinuteOccupancy {
                            minute,
                            mean: state.weighted / state.observed_s.max(1e-9),
                            peak: state.peak,
                        },
                    ));
                    state.weighted = 0.0;
                    state.observed_s = 0.0;
                    state.peak = people;
                }
            }
            from = until;
        }
    }

    fn crossings(
        &self,
        track: u64,
        from: [f64; 2],
        to: [f64; 2],
        t_ns: i64,
        out: &mut Vec<Happened>,
    ) {
        for (l, (points, in_side)) in self.lines.iter().enumerate() {
            for seg in points.windows(2) {
                let Some(side_to) = crossed(seg[0], seg[1], from, to) else {
                    continue;
                };
                let direction = if side_to == *in_side {
                    Direction::In
                } else {
                    Direction::Out
                };
                out.push(Happened::Crossed {
                    line: l,
                    track,
                    t_ns,
                    direction,
                });
                break;
            }
        }
    }
}

/// Twice the signed area of (a, b, p): positive when p is left of a→b on a
/// page with y pointing down (counter-clockwise as drawn).
fn orient(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (a[1] - p[1]) - (b[1] - a[1]) * (a[0] - p[0])
}

/// If the move `from` → `to` crosses the segment a–b (properly, or ending on
/// it from one side), the side of a→b it ends on.
fn crossed(a: [f64; 2], b: [f64; 2], from: [f64; 2], to: [f64; 2]) -> Option<Side> {
    let (s_from, s_to) = (orient(a, b, from), orient(a, b, to));
    let (s_a, s_b) = (orient(from, to, a), orient(from, to, b));
    let straddles = (s_from < 0.0 && s_to > 0.0) || (s_from > 0.0 && s_to < 0.0);
    let on_segment = (s_a <= 0.0 && s_b >= 0.0) || (s_a >= 0.0 && s_b <= 0.0);
    (straddles && on_segment).then_some(if s_to > 0.0 { Side::Left } else { Side::Right })
}

/// Even-odd rule.
fn inside(polygon: &[[f64; 2]], p: [f64; 2]) -> bool {
    let mut inside = false;
    let n = polygon.len();
    for i in 0..n {
        let (a, b) = (polygon[i], polygon[(i + 1) % n]);
        if (a[1] > p[1]) != (b[1] > p[1]) {
            let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
            if p[0] < x {
                inside = !inside;
            }
        }
    }
    inside
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: i64 = 1_000_000_000;

    fn square() -> Vec<[f64; 2]> {
        vec![[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]
    }

    #[test]
    fn a_visit_is_entered_left_and_its_dwell_measured() {
        let mut c = Counter::new(vec![square()], vec![]);
        assert!(c.observe(0, &[(7, [-1.0, 5.0])]).is_empty());
        assert_eq!(
            c.observe(2 * S, &[(7, [1.0, 5.0])]),
            [Happened::Entered {
                zone: 0,
                track: 7,
                t_ns: 2 * S
            }]
        );
        assert_eq!(c.people(0), 1);
        c.observe(10 * S, &[(7, [9.0, 5.0])]);
        let left = c.observe(14 * S, &[(7, [11.0, 5.0])]);
        assert_eq!(
            left,
            [Happened::Left {
                zone: 0,
                track: 7,
                entered_ns: 2 * S,
                t_ns: 14 * S,
                dwell_s: 12.0
            }]
        );
        // A track that ends inside leaves.
        c.observe(20 * S, &[(8, [5.0, 5.0])]);
        let gone = c.observe(26 * S, &[]);
        assert!(matches!(gone[..], [Happened::Left { track: 8, dwell_s, .. }] if dwell_s == 6.0));
        assert_eq!(c.people(0), 0);
    }

    #[test]
    fn a_minute_s_mean_is_weighted_by_time_and_its_peak_kept() {
        let mut c = Counter::new(vec![square()], vec![]);
        // Two people for the first 15 s of minute 0, one for 30 s, none after.
        c.observe(0, &[(1, [1.0, 1.0]), (2, [2.0, 2.0])]);
        c.observe(15 * S, &[(1, [1.0, 1.0])]);
        c.observe(45 * S, &[]);
        assert!(c.take_minutes().is_empty());
        c.observe(61 * S, &[]);
        let minutes = c.take_minutes();
        assert_eq!(minutes.len(), 1);
        let (zone, m) = minutes[0];
        assert_eq!((zone, m.minute, m.peak), (0, 0, 2));
        // (2 × 15 + 1 × 30) / 60.
        assert!((m.mean - 1.0).abs() < 1e-9, "{}", m.mean);
    }

    #[test]
    fn crossings_are_counted_in_and_out_by_the_configured_side() {
        // A line along x = 5 from the top down: its left side (as drawn, y
        // down) is x > 5.
        let line = vec![[5.0, 0.0], [5.0, 10.0]];
        let mut c = Counter::new(vec![], vec![(line, Side::Left)]);
        c.observe(0, &[(1, [2.0, 5.0])]);
        let h = c.observe(S, &[(1, [8.0, 5.0])]);
        assert!(
            matches!(
                h[..],
                [Happened::Crossed {
                    line: 0,
                    track: 1,
                    direction: Direction::In,
                    ..
                }]
            ),
            "{h:?}"
        );
        let h = c.observe(2 * S, &[(1, [3.0, 6.0])]);
        assert!(
            matches!(
                h[..],
                [Happened::Crossed {
                    direction: Direction::Out,
                    ..
                }]
            ),
            "{h:?}"
        );
        // Moving beside the line, or past its end, is no crossing.
        assert!(c.observe(3 * S, &[(1, [3.0, 9.0])]).is_empty());
        assert!(c.observe(4 * S, &[(1, [8.0, 12.0])]).is_empty());
    }

    #[test]
    fn a_polyline_counts_one_crossing_per_move() {
        let line = vec![[0.0, 5.0], [5.0, 5.0], [10.0, 5.0]];
        let mut c = Counter::new(vec![], vec![(line, Side::Right)]);
        c.observe(0, &[(1, [5.0, 0.0])]);
        let h = c.observe(S, &[(1, [5.0, 9.0])]);
        assert_eq!(h.len(), 1, "{h:?}");
    }
}
