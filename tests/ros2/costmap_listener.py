#!/usr/bin/env python3
"""An independent ROS 2 subscriber for isochron's activity cost map.

It uses Eclipse Cyclone DDS (the `cyclonedds` package from PyPI) and nothing of
isochron or ROS: the message types are declared here from the ROS 2 `.msg`
definitions with their DDS names (`nav_msgs::msg::dds_::OccupancyGrid_`,
`map_msgs::msg::dds_::OccupancyGridUpdate_`), the topics are the DDS names of the
ROS 2 topics (`rt/<topic>`), and the QoS is what Nav2's StaticLayer asks for:
reliable and transient-local for the grid, reliable and volatile for the updates.

Every received message is printed to standard output as one JSON object per line
and flushed at once, so the test reading it sees messages as they arrive:

    {"kind": "grid", "frame_id": ..., "stamp": [sec, nanosec], "resolution": ...,
     "width": ..., "height": ..., "origin": [x, y, z, qx, qy, qz, qw], "data": [...]}
    {"kind": "update", "frame_id": ..., "x": ..., "y": ..., "width": ...,
     "height": ..., "data": [...]}

With --people, --markers, --speed-info, --speed-mask and --forecast it also reads
`geometry_msgs/PoseArray` ("people": "stamp", "frame_id", "poses": [[x, y], ...]),
`visualization_msgs/MarkerArray` ("markers": "markers": [{"ns", "id", "type",
"action", "points": [[x, y], ...], "text"}]), `nav2_msgs/CostmapFilterInfo`
("filter_info": "type", "filter_mask_topic", "base", "multiplier") and two more
grids ("speed_mask", "forecast": like "grid"), all reliable; the markers, the
filter info, the mask and the forecast transient-local (latched).

The first line is {"kind": "ready"} once the readers exist. DDS stays on this
machine: Cyclone is bound to the loopback interface, without multicast, and finds
its peers through unicast discovery on 127.0.0.1.

Usage: costmap_listener.py --domain D --topic /isochron/activity_costmap
       [--updates] [--grids N] [--timeout S] [--people T] [--markers T]
       [--speed-info T] [--speed-mask T] [--forecast T] [--multicast]

--multicast: Cyclone's default discovery (multicast SPDP on every interface)
instead of loopback-only unicast.
"""

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass

LOOPBACK_ONLY = """<CycloneDDS><Domain id="any">
  <General>
    <Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>
    <AllowMulticast>false</AllowMulticast>
  </General>
  <Discovery>
    <ParticipantIndex>auto</ParticipantIndex>
    <MaxAutoParticipantIndex>30</MaxAutoParticipantIndex>
    <Peers><Peer address="127.0.0.1"/></Peers>
  </Discovery>
</Domain></CycloneDDS>"""


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--domain", type=int, required=True)
    parser.add_argument("--topic", required=True, help="ROS 2 topic of the grid")
    parser.add_argument("--updates", action="store_true", help="also read <topic>_updates")
    parser.add_argument("--grids", type=int, default=0, help="exit after this many grids")
    parser.add_argument("--timeout", type=float, default=60.0, help="exit after this many seconds")
    for extra in ["people", "markers", "speed-info", "speed-mask", "forecast"]:
        parser.add_argument("--" + extra, help="ROS 2 topic to read as well")
    parser.add_argument("--multicast", action="store_true", help="default multicast discovery")
    args = parser.parse_args()

    # Must be set before Cyclone DDS creates its domain.
    if not args.multicast:
        os.environ["CYCLONEDDS_URI"] = LOOPBACK_ONLY
    else:
        os.environ.pop("CYCLONEDDS_URI", None)

    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl.types import float32, float64, int8, int32, sequence, uint8, uint32
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    @dataclass
    class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
        sec: int32
        nanosec: uint32

    @dataclass
    class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
        stamp: Time
        frame_id: str

    @dataclass
    class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
        x: float64
        y: float64
        z: float64

    @dataclass
    class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
        x: float64
        y: float64
        z: float64
        w: float64

    @dataclass
    class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
        position: Point
        orientation: Quaternion

    @dataclass
    class MapMetaData(IdlStruct, typename="nav_msgs::msg::dds_::MapMetaData_"):
        map_load_time: Time
        resolution: float32
        width: uint32
        height: uint32
        origin: Pose

    @dataclass
    class OccupancyGrid(IdlStruct, typename="nav_msgs::msg::dds_::OccupancyGrid_"):
        header: Header
        info: MapMetaData
        data: sequence[int8]

    @dataclass
    class OccupancyGridUpdate(IdlStruct, typename="map_msgs::msg::dds_::OccupancyGridUpdate_"):
        header: Header
        x: int32
        y: int32
        width: uint32
        height: uint32
        data: sequence[int8]

    @dataclass
    class PoseArray(IdlStruct, typename="geometry_msgs::msg::dds_::PoseArray_"):
        header: Header
        poses: sequence[Pose]

    @dataclass
    class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
        x: float64
        y: float64
        z: float64

    @dataclass
    class ColorRGBA(IdlStruct, typename="std_msgs::msg::dds_::ColorRGBA_"):
        r: float32
        g: float32
        b: float32
        a: float32

    @dataclass
    class Duration(IdlStruct, typename="builtin_interfaces::msg::dds_::Duration_"):
        sec: int32
        nanosec: uint32

    @dataclass
    class CompressedImage(IdlStruct, typename="sensor_msgs::msg::dds_::CompressedImage_"):
        header: Header
        format: str
        data: sequence[uint8]

    @dataclass
    class UVCoordinate(IdlStruct, typename="visualization_msgs::msg::dds_::UVCoordinate_"):
        u: float32
        v: float32

    @dataclass
    class MeshFile(IdlStruct, typename="visualization_msgs::msg::dds_::MeshFile_"):
        filename: str
        data: sequence[uint8]

    # visualization_msgs/msg/Marker as of Iron/Jazzy.
    @dataclass
    class Marker(IdlStruct, typename="visualization_msgs::msg::dds_::Marker_"):
        header: Header
        ns: str
        id: int32
        type: int32
        action: int32
        pose: Pose
        scale: Vector3
        color: ColorRGBA
        lifetime: Duration
        frame_locked: bool
        points: sequence[Point]
        colors: sequence[ColorRGBA]
        texture_resource: str
        texture: CompressedImage
        uv_coordinates: sequence[UVCoordinate]
        text: str
        mesh_resource: str
        mesh_file: MeshFile
        mesh_use_embedded_materials: bool

    @dataclass
    class MarkerArray(IdlStruct, typename="visualization_msgs::msg::dds_::MarkerArray_"):
        markers: sequence[Marker]

    @dataclass
    class CostmapFilterInfo(IdlStruct, typename="nav2_msgs::msg::dds_::CostmapFilterInfo_"):
        header: Header
        type: uint8
        filter_mask_topic: str
        base: float32
        multiplier: float32

    def emit(obj):
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()

    # ROS 2 middlewares send plain CDR (XCDR1): accept it explicitly.
    xcdr1 = Policy.DataRepresentation(use_cdrv0_representation=True, use_xcdrv2_representation=True)
    grid_qos = Qos(
        Policy.Reliability.Reliable(duration(seconds=1)),
        Policy.Durability.TransientLocal,
        Policy.History.KeepLast(1),
        xcdr1,
    )
    updates_qos = Qos(
        Policy.Reliability.Reliable(duration(seconds=1)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(10),
        xcdr1,
    )
    participant = DomainParticipant(args.domain)
    def dds(topic):
        return "rt" + (topic if topic.startswith("/") else "/" + topic)

    dds_name = dds(args.topic)
    grid_reader = DataReader(participant, Topic(participant, dds_name, OccupancyGrid), qos=grid_qos)
    updates_reader = None
    if args.updates:
        updates_reader = DataReader(
            participant, Topic(participant, dds_name + "_updates", OccupancyGridUpdate), qos=updates_qos
        )
    people_qos = Qos(
        Policy.Reliability.Reliable(duration(seconds=1)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(10),
        xcdr1,
    )
    extra = []  # (kind, reader)
    for kind, topic, cls, qos in [
        ("people", args.people, PoseArray, people_qos),
        ("markers", args.markers, MarkerArray, grid_qos),
        ("filter_info", args.speed_info, CostmapFilterInfo, grid_qos),
        ("speed_mask", args.speed_mask, OccupancyGrid, grid_qos),
        ("forecast", args.forecast, OccupancyGrid, grid_qos),
    ]:
        if topic:
            extra.append((kind, DataReader(participant, Topic(participant, dds(topic), cls), qos=qos)))
    emit({"kind": "ready"})

    def grid_json(kind, msg):
        o = msg.info.origin
        return {
            "kind": kind,
            "frame_id": msg.header.frame_id,
            "stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec],
            "resolution": msg.info.resolution,
            "width": msg.info.width,
            "height": msg.info.height,
            "origin": [o.position.x, o.position.y, o.position.z,
                       o.orientation.x, o.orientation.y, o.orientation.z, o.orientation.w],
            "data": list(msg.data),
        }

    def extra_json(kind, msg):
        if kind == "people":
            return {
                "kind": kind,
                "frame_id": msg.header.frame_id,
                "stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec],
                "poses": [[p.position.x, p.position.y] for p in msg.poses],
            }
        if kind == "markers":
            return {
                "kind": kind,
                "markers": [
                    {
                        "ns": m.ns,
                        "id": m.id,
                        "type": m.type,
                        "action": m.action,
                        "frame_id": m.header.frame_id,
                        "points": [[p.x, p.y] for p in m.points],
                        "text": m.text,
                    }
                    for m in msg.markers
                ],
            }
        if kind == "filter_info":
            return {
                "kind": kind,
                "frame_id": msg.header.frame_id,
                "type": msg.type,
                "filter_mask_topic": msg.filter_mask_topic,
                "base": msg.base,
                "multiplier": msg.multiplier,
            }
        return grid_json(kind, msg)

    grids = 0
    end = time.monotonic() + args.timeout
    while time.monotonic() < end:
        got = False
        for msg in grid_reader.take(N=16):
            got = True
            grids += 1
            o = msg.info.origin
            emit(
                {
                    "kind": "grid",
                    "frame_id": msg.header.frame_id,
                    "stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec],
                    "resolution": msg.info.resolution,
                    "width": msg.info.width,
                    "height": msg.info.height,
                    "origin": [
                        o.position.x,
                        o.position.y,
                        o.position.z,
                        o.orientation.x,
                        o.orientation.y,
                        o.orientation.z,
                        o.orientation.w,
                    ],
                    "data": list(msg.data),
                }
            )
        if updates_reader is not None:
            for msg in updates_reader.take(N=64):
                got = True
                emit(
                    {
                        "kind": "update",
                        "frame_id": msg.header.frame_id,
                        "stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec],
                        "x": msg.x,
                        "y": msg.y,
                        "width": msg.width,
                        "height": msg.height,
                        "data": list(msg.data),
                    }
                )
        for kind, reader in extra:
            for msg in reader.take(N=16):
                got = True
                emit(extra_json(kind, msg))
        if args.grids and grids >= args.grids:
            break
        if not got:
            time.sleep(0.02)
    emit({"kind": "done", "grids": grids})


if __name__ == "__main__":
    main()
