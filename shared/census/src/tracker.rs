//! Tracks of people on one plane (the floor, in metres, where the camera has
//! floor points; else the image, in pixels), from detections that come seconds
//! apart.
//!
//! The SORT family (Bewley et al., "Simple Online and Realtime Tracking", ICIP
//! 2016) with ByteTrack's two-stage association (Zhang et al., "ByteTrack:
//! Multi-Object Tracking by Associating Every Detection Box", ECCV 2022): each
//! track is a constant-velocity Kalman filter; at each detection time the
//! tracks are predicted, the confident detections are assigned to them by the
//! Hungarian algorithm (`pathfinding::kuhn_munkres_min`), then the weak ones
//! to the tracks left over; a confident detection nobody took starts a track,
//! and a track unseen for `lost_s` ends. Unlike the trackers of those papers
//! (and the crates that implement them), which associate boxes by their
//! overlap between frames 40 ms apart, this one associates positions by their
//! distance to the prediction, gated by how far a person can walk in the time
//! between two detections: a census detects every two seconds, and a walking
//! person's box of two seconds before no longer overlaps them.

use pathfinding::kuhn_munkres::kuhn_munkres_min;
use pathfinding::matrix::Matrix;

/// How the tracker associates and keeps tracks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackerParams {
    /// A detection this far (plane units) from a prediction may still be that
    /// track, plus `max_speed` × the time since it was last seen.
    pub gate: f64,
    /// The fastest a person moves, plane units per second.
    pub max_speed: f64,
    /// A track unseen this long (seconds) has ended.
    pub lost_s: f64,
    /// Detections at least this confident are matched first and may start tracks.
    pub high_score: f32,
    /// Detections below this are ignored; between the two they only continue
    /// tracks.
    pub low_score: f32,
}

impl TrackerParams {
    /// Parameters for the floor, in metres: a 0.8 m gate, people at up to
    /// 2.5 m/s, a track ended after `lost_s`.
    pub fn floor(lost_s: f64) -> Self {
        TrackerParams {
            gate: 0.8,
            max_speed: 2.5,
            lost_s,
            high_score: 0.5,
            low_score: 0.2,
        }
    }
}

/// One person seen at a time: where, and how sure the detector is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    /// Position on the plane (the foot point of the person's box).
    pub at: [f64; 2],
    /// Detector confidence, 0..1.
    pub score: f32,
}

/// A constant-velocity Kalman filter of one axis: position and velocity.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Axis {
    x: f64,
    v: f64,
    /// Covariance [[pxx, pxv], [pxv, pvv]].
    p: [f64; 3],
}

/// Measurement noise (plane units², a detection's foot point) and process
/// noise (acceleration, units²/s³) of the filter, relative to the gate.
const MEASUREMENT: f64 = 0.05;
const ACCELERATION: f64 = 0.5;

impl Axis {
    fn new(x: f64, scale: f64) -> Self {
        Axis {
            x,
            v: 0.0,
            p: [MEASUREMENT * scale * scale, 0.0, scale * scale],
        }
    }

    fn predicted(&self, dt: f64) -> f64 {
        self.x + self.v * dt
    }

    fn predict(&mut self, dt: f64, scale: f64) {
        let [xx, xv, vv] = self.p;
        let q = ACCELERATION * scale * scale;
        self.x += self.v * dt;
        self.p = [
            xx + 2.0 * dt * xv + dt * dt * vv + q * dt.powi(3) / 3.0,
            xv + dt * vv + q * dt * dt / 2.0,
            vv + q * dt,
        ];
    }

    fn correct(&mut self, z: f64, scale: f64) {
        let [xx, xv, vv] = self.p;
        let s = xx + MEASUREMENT * scale * scale;
        let (kx, kv) = (xx / s, xv / s);
        let innovation = z - self.x;
        self.x += kx * innovation;
        self.v += kv * innovation;
        self.p = [(1.0 - kx) * xx, (1.0 - kx) * xv, vv - kv * xv];
    }
}

/// A person followed across detections.
#[derive(Debug, Clone, PartialEq)]
pub struct Track {
    /// Unique for the tracker's life, from 1.
    pub id: u64,
    /// When it was first seen, ns.
    pub first_ns: i64,
    /// When it was last seen, ns.
    pub last_ns: i64,
    /// Detections it took.
    pub hits: u32,
    axes: [Axis; 2],
    /// The time the filter state is at, ns.
    at_ns: i64,
}

impl Track {
    /// Where the track is expected at `t_ns` (its last position moved on at
    /// its velocity).
    pub fn position_at(&self, t_ns: i64) -> [f64; 2] {
        let dt = secs(t_ns - self.at_ns);
        [self.axes[0].predicted(dt), self.axes[1].predicted(dt)]
    }

    /// Its velocity, plane units per second.
    pub fn velocity(&self) -> [f64; 2] {
        [self.axes[0].v, self.axes[1].v]
    }
}

/// What one [`Tracker::update`] changed.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Update {
    /// Tracks started by this update.
    pub started: Vec<u64>,
    /// Tracks ended by this update (unseen for `lost_s`), with their state.
    pub ended: Vec<Track>,
    /// Detections that continued a track: (detection index, track id).
    pub matched: Vec<(usize, u64)>,
}

/// The tracks of one camera.
#[derive(Debug, Clone)]
pub struct Tracker {
    params: TrackerParams,
    tracks: Vec<Track>,
    next_id: u64,
}

/// Costs are whole units of a thousandth of the gate's unit (mm on the floor).
const COST_SCALE: f64 = 1000.0;

fn secs(ns: i64) -> f64 {
    ns as f64 / 1e9
}

impl Tracker {
    /// A tracker without tracks.
    pub fn new(params: TrackerParams) -> Self {
        Tracker {
            params,
            tracks: Vec::new(),
            next_id: 1,
        }
    }

    /// The live tracks.
    pub fn tracks(&self) -> &[Track] {
        &self.tracks
    }

    /// Takes the detections of time `t_ns` (ns, not before the last update;
    /// an earlier time is taken as the last one). Non-finite positions and
    /// scores are ignored.
    pub fn update(&mut self, t_ns: i64, detections: &[Detection]) -> Update {
        let mut update = Update::default();
        let p = self.params;
        // Tracks unseen for longer than `lost_s` end before they could take a
        // detection.
        let lost_ns = (p.lost_s * 1e9) as i64;
        let (ended, kept): (Vec<Track>, Vec<Track>) = std::mem::take(&mut self.tracks)
            .into_iter()
            .partition(|t| t_ns.saturating_sub(t.last_ns) > lost_ns);
        self.tracks = kept;
        update.ended = ended;
        let usable = |d: &Detection| d.at.iter().all(|v| v.is_finite()) && d.score >= p.low_score;
        let (high, low): (Vec<usize>, Vec<usize>) = (0..detections.len())
            .filter(|&i| usable(&detections[i]))
            .partition(|&i| detections[i].score >= p.high_score);
        let mut free: Vec<usize> = (0..self.tracks.len()).collect();
        for stage in [&high, &low] {
            let pairs = self.assign(t_ns, &free, stage, detections);
            for &(k, i) in &pairs {
                self.correct(k, t_ns, detections[i].at);
                update.matched.push((i, self.tracks[k].id));
            }
            free.retain(|k| !pairs.iter().any(|(m, _)| m == k));
        }
        for &i in &high {
            if !update.matched.iter().any(|(m, _)| *m == i) {
                let id = self.start(t_ns, detections[i].at);
                update.started.push(id);
            }
        }
        update
    }

    /// Ends every track (the stream ended): they are returned.
    pub fn finish(&mut self) -> Vec<Track> {
        std::mem::take(&mut self.tracks)
    }

    /// The least-cost assignment of `detections[dets]` to `self.tracks[tracks]`
    /// within each track's gate: (track index, detection index) pairs.
    fn assign(
        &self,
        t_ns: i64,
        tracks: &[usize],
        dets: &[usize],
        detections: &[Detection],
    ) -> Vec<(usize, usize)> {
        if tracks.is_empty() || dets.is_empty() {
            return Vec::new();
        }
        let p = self.params;
        let gates: Vec<f64> = tracks
            .iter()
            .map(|&k| {
                let unseen = secs(t_ns.saturating_sub(self.tracks[k].last_ns)).clamp(0.0, p.lost_s);
                p.gate + p.max_speed * unseen
            })
            .collect();
        let n = tracks.len().max(dets.len());
        // A pair beyond its gate, or a padding row or column, costs more than
        // any pair within a gate: it is only taken when nothing better is left,
        // and then dropped.
        let widest = gates.iter().cloned().fold(p.gate, f64::max);
        let beyond = (widest * COST_SCALE).ceil() as i64 + 1;
        let mut costs = Matrix::new(n, n, beyond);
        for (r, &k) in tracks.iter().enumerate() {
            let at = self.tracks[k].position_at(t_ns);
            for (c, &i) in dets.iter().enumerate() {
                let d = detections[i].at;
                let distance = (d[0] - at[0]).hypot(d[1] - at[1]);
                if distance <= gates[r] {
                    costs[(r, c)] = (distance * COST_SCALE).round() as i64;
                }
            }
        }
        let (_, columns) = kuhn_munkres_min(&costs);
        columns
            .iter()
            .enumerate()
            .filter(|&(r, &c)| r < tracks.len() && c < dets.len() && costs[(r, c)] < beyond)
            .map(|(r, &c)| (tracks[r], dets[c]))
            .collect()
    }

    fn correct(&mut self, k: usize, t_ns: i64, at: [f64; 2]) {
        let scale = self.params.gate;
        let track = &mut self.tracks[k];
        let dt = secs(t_ns - track.at_ns).max(0.0);
        for (axis, z) in track.axes.iter_mut().zip(at) {
            axis.predict(dt, scale);
            axis.correct(z, scale);
        }
        track.at_ns = t_ns.max(track.at_ns);
        track.last_ns = track.at_ns;
        track.hits += 1;
    }

    fn start(&mut self, t_ns: i64, at: [f64; 2]) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        let scale = self.params.gate;
        self.tracks.push(Track {
            id,
            first_ns: t_ns,
            last_ns: t_ns,
            hits: 1,
            axes: [Axis::new(at[0], scale), Axis::new(at[1], scale)],
            at_ns: t_ns,
        });
        id
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: i64 = 1_000_000_000;

    fn det(x: f64, y: f64) -> Detection {
        Detection {
            at: [x, y],
            score: 0.9,
        }
    }

    #[test]
    fn two_people_walking_past_each_other_keep_their_ids_at_a_two_second_census() {
        // A walks east, B west, 1.2 m/s, 0.6 m apart sideways; they pass at t = 10 s.
        let mut tracker = Tracker::new(TrackerParams::floor(6.0));
        for step in 0..=10 {
            let t = step as f64 * 2.0;
            let a = det(-12.0 + 1.2 * t, 0.0);
            let b = det(12.0 - 1.2 * t, 0.6);
            let mut u = tracker.update(step * 2 * S, &[a, b]);
            if step == 0 {
                assert_eq!(u.started, [1, 2]);
            } else {
                assert!(u.started.is_empty(), "step {step}: {u:?}");
                u.matched.sort();
                assert_eq!(u.matched, [(0, 1), (1, 2)], "step {step}");
            }
        }
        let v = tracker.tracks()[0].velocity();
        assert!((v[0] - 1.2).abs() < 0.2 && v[1].abs() < 0.2, "{v:?}");
    }

    #[test]
    fn a_person_missed_once_is_kept_and_one_gone_longer_than_lost_s_ends() {
        let mut tracker = Tracker::new(TrackerParams::floor(5.0));
        tracker.update(0, &[det(0.0, 0.0)]);
        tracker.update(2 * S, &[det(2.0, 0.0)]);
        // Missed at 4 s; seen again at 6 s where its velocity says.
        assert!(tracker.update(4 * S, &[]).ended.is_empty());
        let u = tracker.update(6 * S, &[det(6.1, 0.0)]);
        assert_eq!(u.matched, [(0, 1)]);
        // Then gone: ended once unseen for more than 5 s.
        assert!(tracker.update(10 * S, &[]).ended.is_empty());
        let ended = tracker.update(12 * S, &[]).ended;
        assert_eq!(ended.len(), 1);
        assert_eq!(
            (
                ended[0].id,
                ended[0].first_ns,
                ended[0].last_ns,
                ended[0].hits
            ),
            (1, 0, 6 * S, 3)
        );
        assert!(tracker.tracks().is_empty());
    }

    #[test]
    fn a_weak_detection_continues_a_track_but_never_starts_one() {
        let mut tracker = Tracker::new(TrackerParams::floor(5.0));
        let weak = |x| Detection {
            at: [x, 0.0],
            score: 0.3,
        };
        assert!(tracker.update(0, &[weak(0.0)]).started.is_empty());
        tracker.update(S, &[det(0.0, 0.0)]);
        let u = tracker.update(
            2 * S,
            &[
                weak(0.1),
                Detection {
                    at: [9.0, 9.0],
                    score: 0.1,
                },
            ],
        );
        assert_eq!(u.matched, [(0, 1)]);
        assert!(u.started.is_empty());
    }

    #[test]
    fn a_detection_beyond_the_gate_starts_a_new_track() {
        let mut tracker = Tracker::new(TrackerParams::floor(5.0));
        tracker.update(0, &[det(0.0, 0.0)]);
        // 2 s later, 8 m away: 0.8 + 2.5 × 2 = 5.8 m is the farthest it may be.
        let u = tracker.update(2 * S, &[det(8.0, 0.0)]);
        assert_eq!(u.started, [2]);
        assert!(u.matched.is_empty());
    }

    #[test]
    fn bad_input_is_ignored_not_a_panic() {
        let mut tracker = Tracker::new(TrackerParams::floor(5.0));
        let junk = [
            Detection {
                at: [f64::NAN, 0.0],
                score: 0.9,
            },
            Detection {
                at: [f64::INFINITY, 1.0],
                score: 0.9,
            },
            Detection {
                at: [1.0, 1.0],
                score: f32::NAN,
            },
        ];
        assert_eq!(tracker.update(0, &junk), Update::default());
        tracker.update(5 * S, &[det(1e12, -1e12)]);
        // Time going backwards is taken as the last time.
        let u = tracker.update(S, &[det(1e12, -1e12)]);
        assert_eq!(u.matched, [(0, 1)]);
        assert_eq!(tracker.finish().len(), 1);
    }
}
