#!/usr/bin/env python3
"""An independent ROS 2 subscriber for isochron's activity cost map.

It uses Eclipse Cyclone DDS (the `cyclonedds` package from PyPI) and nothing of
isochron or ROS (what it shares with plan_client.py is in ros2_dds.py): the message
types are declared here from the ROS 2 `.msg` definitions with their DDS names (`nav_msgs::msg::dds_::OccupancyGrid_`,
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
import time

from ros2_dds import absolute, configure, emit, reliable_qos, ros_type


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

    configure(args.multicast)

    from cyclonedds.domain import DomainParticipant
    from cyclonedds.idl.types import float32, float64, int8, int32, sequence, uint8, uint32
    from cyclonedds.internal import InvalidSample
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    Time = ros_type("builtin_interfaces/msg/Time", sec=int32, nanosec=uint32)

    Header = ros_type("std_msgs/msg/Header", stamp=Time, frame_id=str)

    Point = ros_type("geometry_msgs/msg/Point", x=float64, y=float64, z=float64)

    Quaternion = ros_type("geometry_msgs/msg/Quaternion", x=float64, y=float64, z=float64, w=float64)

    Pose = ros_type("geometry_msgs/msg/Pose", position=Point, orientation=Quaternion)

    MapMetaData = ros_type(
        "nav_msgs/msg/MapMetaData",
        map_load_time=Time, resolution=float32, width=uint32, height=uint32, origin=Pose,
    )

    OccupancyGrid = ros_type(
        "nav_msgs/msg/OccupancyGrid",
        header=Header, info=MapMetaData, data=sequence[int8],
    )

    OccupancyGridUpdate = ros_type(
        "map_msgs/msg/OccupancyGridUpdate",
        header=Header, x=int32, y=int32, width=uint32, height=uint32, data=sequence[int8],
    )

    PoseArray = ros_type("geometry_msgs/msg/PoseArray", header=Header, poses=sequence[Pose])

    Vector3 = ros_type("geometry_msgs/msg/Vector3", x=float64, y=float64, z=float64)

    ColorRGBA = ros_type("std_msgs/msg/ColorRGBA", r=float32, g=float32, b=float32, a=float32)

    Duration = ros_type("builtin_interfaces/msg/Duration", sec=int32, nanosec=uint32)

    CompressedImage = ros_type(
        "sensor_msgs/msg/CompressedImage",
        header=Header, format=str, data=sequence[uint8],
    )

    UVCoordinate = ros_type("visualization_msgs/msg/UVCoordinate", u=float32, v=float32)

    MeshFile = ros_type("visualization_msgs/msg/MeshFile", filename=str, data=sequence[uint8])

    # visualization_msgs/msg/Marker as of Iron/Jazzy.
    Marker = ros_type(
        "visualization_msgs/msg/Marker",
        header=Header, ns=str, id=int32, type=int32, action=int32, pose=Pose, scale=Vector3,
        color=ColorRGBA, lifetime=Duration, frame_locked=bool, points=sequence[Point],
        colors=sequence[ColorRGBA], texture_resource=str, texture=CompressedImage,
        uv_coordinates=sequence[UVCoordinate], text=str, mesh_resource=str, mesh_file=MeshFile,
        mesh_use_embedded_materials=bool,
    )

    MarkerArray = ros_type("visualization_msgs/msg/MarkerArray", markers=sequence[Marker])

    CostmapFilterInfo = ros_type(
        "nav2_msgs/msg/CostmapFilterInfo",
        header=Header, type=uint8, filter_mask_topic=str, base=float32, multiplier=float32,
    )

    grid_qos = reliable_qos(latched=True, depth=1)
    volatile_qos = reliable_qos(latched=False, depth=10)
    participant = DomainParticipant(args.domain)

    def dds(topic):
        return "rt" + absolute(topic)

    dds_name = dds(args.topic)
    grid_reader = DataReader(participant, Topic(participant, dds_name, OccupancyGrid), qos=grid_qos)
    updates_reader = None
    if args.updates:
        updates_reader = DataReader(
            participant, Topic(participant, dds_name + "_updates", OccupancyGridUpdate), qos=volatile_qos
        )
    extra = []  # (kind, reader)
    for kind, topic, cls, qos in [
        ("people", args.people, PoseArray, volatile_qos),
        ("markers", args.markers, MarkerArray, grid_qos),
        ("filter_info", args.speed_info, CostmapFilterInfo, grid_qos),
        ("speed_mask", args.speed_mask, OccupancyGrid, grid_qos),
        ("forecast", args.forecast, OccupancyGrid, grid_qos),
    ]:
        if topic:
            extra.append((kind, DataReader(participant, Topic(participant, dds(topic), cls), qos=qos)))
    emit({"kind": "ready"})

    def valid(samples):
        """The samples with data: a reader also takes instance state changes (a
        writer gone quiet, disposed), which carry none, as rclpy skips them."""
        return [m for m in samples if not isinstance(m, InvalidSample)]

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
        for msg in valid(grid_reader.take(N=16)):
            got = True
            grids += 1
            emit(grid_json("grid", msg))
        if updates_reader is not None:
            for msg in valid(updates_reader.take(N=64)):
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
            for msg in valid(reader.take(N=16)):
                got = True
                emit(extra_json(kind, msg))
        if args.grids and grids >= args.grids:
            break
        if not got:
            time.sleep(0.02)
    emit({"kind": "done", "grids": grids})


if __name__ == "__main__":
    main()
