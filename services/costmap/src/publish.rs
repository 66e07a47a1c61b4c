//! What the cost-map stage sends over ROS 2 and what it counts: the grid (full or
//! as an update, as the [`DeltaTracker`] decides), the confirmed people (made by
//! [`crate::people`]), and the counters of the status line.

use std::hash::{Hash, Hasher};
use std::time::Instant;

use isochron_planning::grid::MapGrid;
use isochron_planning::raster::Footprint;
use isochron_ros2::msgs::{
    Header, MapMetaData, Marker, MarkerArray, OccupancyGrid, OccupancyGridUpdate, Point, Pose,
    Quaternion, RosDuration, Time,
};
use isochron_ros2::{PublishError, RosOutput};
use isochron_runtime::stage::Warnings;

use crate::bridge::{Bridge, Confirmed};
use crate::delta::{DeltaTracker, Output};
use crate::people;

/// Counters for the status line.
#[derive(Default)]
pub(crate) struct Counters {
    /// Publish failures, rate-limited: a stalled DDS fails every tick.
    pub(crate) warnings: Warnings,
    pub(crate) grids: u64,
    pub(crate) updates: u64,
    pub(crate) publish_errors: u64,
    pub(crate) plans: u64,
    pub(crate) snapshots: u64,
    pub(crate) confirmed: u64,
    pub(crate) people: u64,
    pub(crate) markers: u64,
    pub(crate) people_markers: u64,
    pub(crate) masks: u64,
    pub(crate) forecasts: u64,
}

impl Counters {
    /// Counts one publish of `what`: into the counter `sent` picks if it went out
    /// (then true), else as a publish error with a warning.
    pub(crate) fn published(
        &mut self,
        what: &str,
        result: Result<(), PublishError>,
        sent: fn(&mut Counters) -> &mut u64,
    ) -> bool {
        match result {
            Ok(()) => {
                *sent(self) += 1;
                true
            }
            Err(e) => {
                self.publish_errors += 1;
                self.warnings
                    .warn("publish", || format!("publishing {what} failed: {e}"));
                false
            }
        }
    }
}

/// The ROS 2 side: the output and what was sent.
pub(crate) struct Ros {
    pub(crate) output: RosOutput,
    pub(crate) tracker: DeltaTracker,
    pub(crate) geometry: u64,
    pub(crate) frame_id: String,
    /// `costmap.publish_unknown`: false sends 0 instead of -1.
    pub(crate) publish_unknown: bool,
    /// When the forecast is next computed.
    pub(crate) next_forecast: Instant,
    /// Each camera's footprint on its store's block grid.
    pub(crate) forecast_footprints: Vec<Option<Footprint>>,
    /// The last speed mask sent.
    pub(crate) mask_sent: Option<Vec<i8>>,
    /// The camera frame sizes the last markers were drawn with (`None`: none sent).
    pub(crate) markers_sent: Option<Vec<Option<(u32, u32)>>>,
    /// Markers drawn in each camera's last people markers (to delete what the
    /// next draws no more).
    pub(crate) people_markers_sent: Vec<usize>,
    /// How long a person's marker stays without news: `costmap.confirm_hold_s`.
    pub(crate) people_lifetime: RosDuration,
}

/// A hash of what makes two grids incompatible (size, resolution, origin).
pub(crate) fn geometry_key(grid: &MapGrid) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    (grid.width, grid.height).hash(&mut h);
    for v in [grid.resolution, grid.origin_x, grid.origin_y, grid.yaw] {
        v.to_bits().hash(&mut h);
    }
    h.finish()
}

/// Publishes the `placed` people camera `k`'s detected frame (capture time
/// `capture_ns`) just added to the bridge, as a `PoseArray` in the map frame, and
/// the camera's confirmed people as markers ([`crate::people`]).
pub(crate) fn publish_people(
    ros: &mut Ros,
    bridge: &Bridge,
    k: usize,
    placed: usize,
    capture_ns: i64,
    counters: &mut Counters,
) {
    let Some(cam) = bridge.cameras.get(k) else {
        return;
    };
    let header = Header {
        stamp: Time::from_utc_ns(capture_ns),
        frame_id: ros.frame_id.clone(),
    };
    let confirmed: Vec<Confirmed> = cam.confirmed.iter().copied().collect();
    let newest = &confirmed[confirmed.len().saturating_sub(placed)..];
    let result = ros
        .output
        .people
        .publish(people::poses(newest, header.clone()));
    counters.published("people", result, |c| &mut c.people);
    let Some(homography) = &cam.homography else {
        return;
    };
    if ros.people_markers_sent.len() <= k {
        ros.people_markers_sent.resize(k + 1, 0);
    }
    let markers = people::markers(
        &cam.id,
        homography,
        &confirmed,
        ros.people_markers_sent[k],
        &header,
        ros.people_lifetime,
    );
    let drawn = markers.iter().filter(|m| m.action == Marker::ADD).count();
    let result = ros.output.people_markers.publish(MarkerArray { markers });
    if counters.published("the people markers", result, |c| &mut c.people_markers) {
        ros.people_markers_sent[k] = drawn;
    }
}

/// A full grid message of `grid`'s geometry.
pub(crate) fn occupancy_grid(
    grid: &MapGrid,
    frame_id: &str,
    stamp_ns: i64,
    data: Vec<i8>,
) -> OccupancyGrid {
    let stamp = Time::from_utc_ns(stamp_ns);
    OccupancyGrid {
        header: Header {
            stamp,
            frame_id: frame_id.to_string(),
        },
        info: MapMetaData {
            map_load_time: stamp,
            resolution: grid.resolution as f32,
            width: grid.width,
            height: grid.height,
            origin: Pose {
                position: Point {
                    x: grid.origin_x,
                    y: grid.origin_y,
                    z: 0.0,
                },
                orientation: Quaternion::from_yaw(grid.yaw),
            },
        },
        data,
    }
}

/// Sets the unknown (-1) cells to 0, for `costmap.publish_unknown = false`.
pub fn unknown_as_free(cells: &mut [i8]) {
    for c in cells.iter_mut().filter(|c| **c < 0) {
        *c = 0;
    }
}

/// Publishes what the tracker decides; true if something went out.
pub(crate) fn publish(
    ros: &mut Ros,
    grid: &MapGrid,
    cells: &[i8],
    stamp_ns: i64,
    now: Instant,
    counters: &mut Counters,
) -> bool {
    let header = Header {
        stamp: Time::from_utc_ns(stamp_ns),
        frame_id: ros.frame_id.clone(),
    };
    let result = match ros.tracker.next(cells, grid.width, ros.geometry, now) {
        Output::Nothing => return false,
        Output::Full => {
            counters.grids += 1;
            ros.output.grid.publish(OccupancyGrid {
                header: header.clone(),
                ..occupancy_grid(grid, &ros.frame_id, stamp_ns, cells.to_vec())
            })
        }
        Output::Update {
            x,
            y,
            width,
            height,
            data,
        } => {
            counters.updates += 1;
            ros.output.updates.publish(OccupancyGridUpdate {
                header,
                x: x as i32,
                y: y as i32,
                width,
                height,
                data,
            })
        }
    };
    if let Err(e) = result {
        counters.publish_errors += 1;
        // Subscribers must not miss a delta: the next tick sends the full grid.
        ros.tracker.reset();
        counters
            .warnings
            .warn("publish", || format!("publishing to ROS 2 failed: {e}"));
        return false;
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_cells_become_free_only_when_asked() {
        let mut cells = vec![-1, 0, 42, 99, -1];
        unknown_as_free(&mut cells);
        assert_eq!(cells, vec![0, 0, 42, 99, 0]);
    }
}
