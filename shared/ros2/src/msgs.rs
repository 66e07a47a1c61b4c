//! The ROS 2 messages the bridge publishes, as plain serde structs in CDR field
//! order (the order of the `.msg` definitions), so that any ROS 2 middleware reads
//! them as `nav_msgs/msg/OccupancyGrid`, `map_msgs/msg/OccupancyGridUpdate`,
//! `geometry_msgs/msg/PoseArray`, `visualization_msgs/msg/MarkerArray` and
//! `nav2_msgs/msg/CostmapFilterInfo` (Jazzy's definition, the release
//! `ros2-client` is built for), the planning services' requests and
//! responses (ros/isochron_msgs), and the route server's
//! `nav2_msgs/srv/DynamicEdges`, which the bridge calls.
//!
//! No ROS install is needed: the DDS type names are
//! `<package>::msg::dds_::<Type>_` ([`crate::spec::types`]) and the serialised
//! form is plain (XCDR1) little-endian CDR, which is what every ROS 2 middleware
//! exchanges, on DDS and on Zenoh. All the bridge's ROS 2 types live here.

use serde::{Deserialize, Serialize};

/// `builtin_interfaces/msg/Time`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    /// Seconds since the Unix epoch.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl Time {
    /// The time of a UTC nanosecond instant (clamped to the range of `sec`).
    pub fn from_utc_ns(utc_ns: i64) -> Time {
        let sec = utc_ns
            .div_euclid(1_000_000_000)
            .clamp(i32::MIN as i64, i32::MAX as i64);
        Time {
            sec: sec as i32,
            nanosec: utc_ns.rem_euclid(1_000_000_000) as u32,
        }
    }
}

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Time of the data.
    pub stamp: Time,
    /// Coordinate frame of the data.
    pub frame_id: String,
}

/// `geometry_msgs/msg/Point`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Point {
    /// x, metres.
    pub x: f64,
    /// y, metres.
    pub y: f64,
    /// z, metres.
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

impl Quaternion {
    /// A rotation of `yaw` radians about z.
    pub fn from_yaw(yaw: f64) -> Quaternion {
        Quaternion {
            x: 0.0,
            y: 0.0,
            z: (yaw / 2.0).sin(),
            w: (yaw / 2.0).cos(),
        }
    }
}

/// `geometry_msgs/msg/Pose`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Position.
    pub position: Point,
    /// Orientation.
    pub orientation: Quaternion,
}

/// `nav_msgs/msg/MapMetaData`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MapMetaData {
    /// When the map was loaded (here: the time of the data).
    pub map_load_time: Time,
    /// Cell edge, metres.
    pub resolution: f32,
    /// Cells per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Pose of cell (0, 0)'s corner in the frame.
    pub origin: Pose,
}

/// `nav_msgs/msg/OccupancyGrid`: row-major, row 0 at the origin, values 0..=100 or
/// -1 (unknown).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OccupancyGrid {
    /// Stamp and frame.
    pub header: Header,
    /// Geometry.
    pub info: MapMetaData,
    /// Cells.
    pub data: Vec<i8>,
}

/// `map_msgs/msg/OccupancyGridUpdate`: new values for a rectangle of a grid
/// published before on the same topic (without `_updates`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OccupancyGridUpdate {
    /// Stamp and frame.
    pub header: Header,
    /// First column of the rectangle.
    pub x: i32,
    /// First row of the rectangle.
    pub y: i32,
    /// Columns of the rectangle.
    pub width: u32,
    /// Rows of the rectangle.
    pub height: u32,
    /// The rectangle's cells, row-major.
    pub data: Vec<i8>,
}

/// `nav2_msgs/msg/CostmapFilterInfo`: which filter a mask is for and how its
/// values read (`value = base + multiplier · mask`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CostmapFilterInfo {
    /// Stamp and frame.
    pub header: Header,
    /// [`CostmapFilterInfo::SPEED_LIMIT_PERCENT`], ...
    #[serde(rename = "type")]
    pub kind: u8,
    /// The mask's ROS 2 topic.
    pub filter_mask_topic: String,
    /// Added to `multiplier · mask`.
    pub base: f32,
    /// Factor of the mask value.
    pub multiplier: f32,
}

impl CostmapFilterInfo {
    /// Nav2's SpeedFilter, limits in percent of the maximum speed.
    pub const SPEED_LIMIT_PERCENT: u8 = 1;
}

/// `geometry_msgs/msg/PoseArray`: poses in one frame at one time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseArray {
    /// Stamp and frame.
    pub header: Header,
    /// The poses.
    pub poses: Vec<Pose>,
}

/// `geometry_msgs/msg/Vector3`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `std_msgs/msg/ColorRGBA`, components 0..=1.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ColorRGBA {
    /// Red.
    pub r: f32,
    /// Green.
    pub g: f32,
    /// Blue.
    pub b: f32,
    /// Opacity.
    pub a: f32,
}

/// `builtin_interfaces/msg/Duration`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RosDuration {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl RosDuration {
    /// `seconds` (at least 0, at most `i32::MAX`) as a duration.
    pub fn from_secs_f64(seconds: f64) -> RosDuration {
        let s = seconds.clamp(0.0, i32::MAX as f64);
        RosDuration {
            sec: s.trunc() as i32,
            nanosec: ((s.fract() * 1e9) as u32).min(999_999_999),
        }
    }
}

/// `sensor_msgs/msg/CompressedImage` (a marker's texture; the bridge sends none).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CompressedImage {
    /// Stamp and frame.
    pub header: Header,
    /// `jpeg`, `png`, ...
    pub format: String,
    /// The image file's bytes.
    pub data: Vec<u8>,
}

/// `visualization_msgs/msg/UVCoordinate`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct UvCoordinate {
    /// u.
    pub u: f32,
    /// v.
    pub v: f32,
}

/// `visualization_msgs/msg/MeshFile`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MeshFile {
    /// File name.
    pub filename: String,
    /// Its bytes.
    pub data: Vec<u8>,
}

/// `visualization_msgs/msg/Marker` (Jazzy: with the texture and mesh fields that
/// Iron added).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Marker {
    /// Stamp and frame.
    pub header: Header,
    /// Namespace: with `id`, what a later marker replaces.
    pub ns: String,
    /// Id within the namespace.
    pub id: i32,
    /// [`Marker::LINE_STRIP`], [`Marker::TEXT_VIEW_FACING`], ...
    #[serde(rename = "type")]
    pub kind: i32,
    /// [`Marker::ADD`] or [`Marker::DELETEALL`].
    pub action: i32,
    /// Pose of the marker's frame.
    pub pose: Pose,
    /// Line width (`x`), text height (`z`), metres.
    pub scale: Vector3,
    /// Colour.
    pub color: ColorRGBA,
    /// 0: forever.
    pub lifetime: RosDuration,
    /// Follow the frame.
    pub frame_locked: bool,
    /// Line strip points.
    pub points: Vec<Point>,
    /// Per-point colours (none).
    pub colors: Vec<ColorRGBA>,
    /// Texture resource (none).
    pub texture_resource: String,
    /// Texture (none).
    pub texture: CompressedImage,
    /// Texture coordinates (none).
    pub uv_coordinates: Vec<UvCoordinate>,
    /// Text of a text marker.
    pub text: String,
    /// Mesh resource (none).
    pub mesh_resource: String,
    /// Mesh (none).
    pub mesh_file: MeshFile,
    /// Mesh materials (no).
    pub mesh_use_embedded_materials: bool,
}

impl Marker {
    /// `type` of a cylinder (`scale` its diameters and height) at `pose`.
    pub const CYLINDER: i32 = 3;
    /// `type` of a line through `points`.
    pub const LINE_STRIP: i32 = 4;
    /// `type` of separate lines, one per pair of `points`.
    pub const LINE_LIST: i32 = 5;
    /// `type` of a text label facing the viewer.
    pub const TEXT_VIEW_FACING: i32 = 9;
    /// `action`: add or replace.
    pub const ADD: i32 = 0;
    /// `action`: delete the marker of this `ns` and `id`.
    pub const DELETE: i32 = 2;
    /// `action`: delete every marker of this publisher's namespace set.
    pub const DELETEALL: i32 = 3;
}

impl Default for Pose {
    fn default() -> Self {
        Pose {
            position: Point::default(),
            orientation: Quaternion::from_yaw(0.0),
        }
    }
}

/// `visualization_msgs/msg/MarkerArray`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MarkerArray {
    /// The markers.
    pub markers: Vec<Marker>,
}

/// `isochron_msgs/msg/CostPoint` (ros/isochron_msgs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CostPoint {
    /// Minute of the day.
    pub minute: u16,
    /// Mean Cost1 over the step (inf: never active; NaN: no data).
    pub cost: f64,
}

/// `isochron_msgs/msg/Window`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Window {
    /// First minute of the day.
    pub start_minute: u16,
    /// End minute, exclusive.
    pub end_minute: u16,
    /// Mean Cost1 over the window.
    pub cost: f64,
}

/// `isochron_msgs/msg/RouteCost`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RouteCost {
    /// Route name.
    pub route: String,
    /// `w1·cost1 + w2·short_term`.
    pub cost2: f64,
    /// Long-term cost at t* = now.
    pub cost1: f64,
    /// Short-term cost.
    pub short_term: f64,
    /// A segment never saw activity.
    pub infinite: bool,
    /// Long-term stood in for missing live activity.
    pub estimated: bool,
    /// No long-term data at this t*.
    pub no_long_term: bool,
}

/// A `string` field read by the CDR rules: a `u32` length that counts the
/// terminating NUL, then that many bytes, the last one NUL and no other, UTF-8.
/// `cdr-encoding` (what RustDDS and ros2-client decode with) drops the last byte
/// whatever it is, so a string sent without its NUL would lose its last character;
/// this one is an error instead. Written as a plain string.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CdrString(pub String);

impl Serialize for CdrString {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(&self.0)
    }
}

impl<'de> Deserialize<'de> for CdrString {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<CdrString, D::Error> {
        struct Strict;
        impl serde::de::Visitor<'_> for Strict {
            type Value = CdrString;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a CDR string")
            }
            fn visit_bytes<E: serde::de::Error>(self, b: &[u8]) -> Result<CdrString, E> {
                CdrString::from_wire(b).map_err(E::custom)
            }
        }
        // A string's wire form is a byte sequence's: length, then the bytes.
        deserializer.deserialize_bytes(Strict)
    }
}

impl CdrString {
    /// The string of `bytes`, the length's worth of a CDR string (NUL included).
    pub fn from_wire(bytes: &[u8]) -> Result<CdrString, String> {
        let Some((&last, text)) = bytes.split_last() else {
            return Err("a string of length 0 (a CDR string's length counts its NUL)".into());
        };
        if last != 0 {
            return Err(format!(
                "a string of {} bytes without its terminating NUL",
                bytes.len()
            ));
        }
        if text.contains(&0) {
            return Err("a string with a NUL inside".into());
        }
        String::from_utf8(text.to_vec())
            .map(CdrString)
            .map_err(|_| "a string that is not UTF-8".into())
    }
}

/// `isochron_msgs/srv/PlanOffline` request.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanOfflineRequest {
    /// Route name.
    pub route: CdrString,
    /// First minute, 0..1440.
    pub start_minute: u16,
    /// End minute, exclusive, 1..=1440.
    pub end_minute: u16,
    /// Minutes per curve point.
    pub step_min: u16,
    /// 0 = Monday .. 6, 7 = today.
    pub weekday: u8,
}

/// `isochron_msgs/srv/PlanOffline` response.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanOfflineResponse {
    /// `STATUS_*` (the values of `PlanStatus`).
    pub status: u8,
    /// Why not OK.
    pub message: String,
    /// Cheapest windows.
    pub windows: Vec<Window>,
    /// The curve.
    pub curve: Vec<CostPoint>,
    /// A segment never saw activity.
    pub infinite: bool,
}

/// `isochron_msgs/srv/PlanNow` request.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanNowRequest {
    /// Route names.
    pub routes: Vec<CdrString>,
}

/// `isochron_msgs/srv/PlanNow` response.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanNowResponse {
    /// `STATUS_*`.
    pub status: u8,
    /// Why not OK.
    pub message: String,
    /// t* of the ranking.
    pub t_star: u16,
    /// Cheapest first.
    pub routes: Vec<RouteCost>,
}

/// `isochron_msgs/msg/GraphPath`: a path through the route graph leaving at one
/// time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GraphPath {
    /// Departure, minute of the day.
    pub departure_minute: u16,
    /// nav2_route node ids, start to goal.
    pub nodes: Vec<u16>,
    /// nav2_route edge ids, in order.
    pub edges: Vec<u16>,
    /// Total cost.
    pub cost: f64,
    /// Its forecast activity part.
    pub activity_cost: f64,
    /// Length, metres.
    pub length_m: f64,
    /// Travel time, seconds.
    pub duration_s: f64,
    /// Edges without long-term data.
    pub unknown_edges: u16,
}

/// `isochron_msgs/srv/PlanGraph` request.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanGraphRequest {
    /// Start node id.
    pub from_node: u16,
    /// Goal node id.
    pub to_node: u16,
    /// First departure, 0..1440.
    pub start_minute: u16,
    /// End minute, exclusive, 1..=1440.
    pub end_minute: u16,
    /// Minutes between departures.
    pub step_min: u16,
    /// 0 = Monday .. 6, 7 = today.
    pub weekday: u8,
}

/// `isochron_msgs/srv/PlanGraph` response.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanGraphResponse {
    /// `STATUS_*` (the values of `PlanStatus`).
    pub status: u8,
    /// Why not OK.
    pub message: String,
    /// Cheapest departure windows.
    pub windows: Vec<Window>,
    /// The cheapest path of each window.
    pub window_paths: Vec<GraphPath>,
    /// The cheapest cost per departure.
    pub curve: Vec<CostPoint>,
    /// The cheapest departure.
    pub best: GraphPath,
    /// The shortest path leaving now, costed the same way.
    pub baseline: GraphPath,
}

/// `nav2_msgs/msg/EdgeCost`: an edge of the route server's graph and its cost.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EdgeCost {
    /// The edge's id.
    pub edgeid: u16,
    /// Its cost, added to the route server's other scorers' as it is.
    pub cost: f32,
}

/// `nav2_msgs/srv/DynamicEdges` request: what the route server's
/// `DynamicEdgesScorer` is told (the bridge is its client).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DynamicEdges {
    /// Edges to close.
    pub closed_edges: Vec<u16>,
    /// Edges to reopen.
    pub opened_edges: Vec<u16>,
    /// Edges whose cost changed.
    pub adjust_edges: Vec<EdgeCost>,
}

impl DynamicEdges {
    /// How many edges the request names (in all three lists).
    pub fn edges(&self) -> usize {
        self.closed_edges.len() + self.opened_edges.len() + self.adjust_edges.len()
    }
}

/// `nav2_msgs/srv/DynamicEdges` response.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct DynamicEdgesResponse {
    /// The scorer took the request.
    pub success: bool,
}

#[cfg(test)]
mod tests {
    use rustdds::CDRSerializerAdapter;
    use rustdds::no_key::SerializerAdapter;

    use super::*;

    /// The CDR bytes of a tiny grid, laid out by hand from the `.msg` definitions:
    /// this is what any ROS 2 subscriber decodes.
    #[test]
    fn occupancy_grid_cdr_layout() {
        let grid = OccupancyGrid {
            header: Header {
                stamp: Time { sec: 7, nanosec: 9 },
                frame_id: "map".into(),
            },
            info: MapMetaData {
                map_load_time: Time { sec: 7, nanosec: 9 },
                resolution: 0.5,
                width: 2,
                height: 1,
                origin: Pose {
                    position: Point {
                        x: 1.0,
                        y: 2.0,
                        z: 0.0,
                    },
                    orientation: Quaternion::from_yaw(0.0),
                },
            },
            data: vec![-1, 100],
        };
        let bytes = CDRSerializerAdapter::<OccupancyGrid>::to_bytes(&grid).unwrap();
        let mut expected: Vec<u8> = Vec::new();
        expected.extend(7i32.to_le_bytes()); // header.stamp.sec @0
        expected.extend(9u32.to_le_bytes()); // nanosec @4
        expected.extend(4u32.to_le_bytes()); // frame_id length incl. NUL @8
        expected.extend(b"map\0"); // @12
        expected.extend(7i32.to_le_bytes()); // info.map_load_time @16
        expected.extend(9u32.to_le_bytes());
        expected.extend(0.5f32.to_le_bytes()); // resolution @24
        expected.extend(2u32.to_le_bytes()); // width @28
        expected.extend(1u32.to_le_bytes()); // height @32
        expected.extend([0u8; 4]); // pad to 8 for the f64s @36
        for v in [1.0f64, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0] {
            expected.extend(v.to_le_bytes()); // origin @40..96
        }
        expected.extend(2u32.to_le_bytes()); // data length @96
        expected.extend([0xff, 100]); // data
        assert_eq!(bytes.as_ref(), expected.as_slice());
    }

    /// `uint16[] closed_edges, uint16[] opened_edges, EdgeCost[] adjust_edges`,
    /// each sequence its length first, an `EdgeCost` a `uint16` and a `float32`
    /// aligned to 4.
    #[test]
    fn dynamic_edges_cdr_layout() {
        let request = DynamicEdges {
            closed_edges: vec![7],
            opened_edges: vec![],
            adjust_edges: vec![EdgeCost {
                edgeid: 9,
                cost: 1.5,
            }],
        };
        let bytes = CDRSerializerAdapter::<DynamicEdges>::to_bytes(&request).unwrap();
        let mut expected: Vec<u8> = Vec::new();
        expected.extend(1u32.to_le_bytes()); // closed_edges length @0
        expected.extend(7u16.to_le_bytes()); // @4
        expected.extend([0u8; 2]); // pad to 4 @6
        expected.extend(0u32.to_le_bytes()); // opened_edges length @8
        expected.extend(1u32.to_le_bytes()); // adjust_edges length @12
        expected.extend(9u16.to_le_bytes()); // edgeid @16
        expected.extend([0u8; 2]); // pad to 4 @18
        expected.extend(1.5f32.to_le_bytes()); // cost @20
        assert_eq!(bytes.as_ref(), expected.as_slice());
        assert_eq!(request.edges(), 2);
    }

    #[test]
    fn time_splits_nanoseconds() {
        assert_eq!(
            Time::from_utc_ns(1_500_000_000_250),
            Time {
                sec: 1500,
                nanosec: 250
            }
        );
        assert_eq!(
            Time::from_utc_ns(-1),
            Time {
                sec: -1,
                nanosec: 999_999_999
            }
        );
    }

    #[test]
    fn yaw_quaternion_is_unit() {
        let q = Quaternion::from_yaw(std::f64::consts::FRAC_PI_2);
        assert!((q.z * q.z + q.w * q.w - 1.0).abs() < 1e-12);
        assert!((q.z - q.w).abs() < 1e-12);
        assert_eq!(Quaternion::from_yaw(0.0).w, 1.0);
    }
}
