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

The first line is {"kind": "ready"} once the readers exist. DDS stays on this
machine: Cyclone is bound to the loopback interface, without multicast, and finds
its peers through unicast discovery on 127.0.0.1.

Usage: costmap_listener.py --domain D --topic /isochron/activity_costmap
       [--updates] [--grids N] [--timeout S]
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
    args = parser.parse_args()

    # Must be set before Cyclone DDS creates its domain.
    os.environ["CYCLONEDDS_URI"] = LOOPBACK_ONLY

    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl.types import float32, float64, int8, int32, sequence, uint32
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
    dds_name = "rt" + (args.topic if args.topic.startswith("/") else "/" + args.topic)
    grid_reader = DataReader(participant, Topic(participant, dds_name, OccupancyGrid), qos=grid_qos)
    updates_reader = None
    if args.updates:
        updates_reader = DataReader(
            participant, Topic(participant, dds_name + "_updates", OccupancyGridUpdate), qos=updates_qos
        )
    emit({"kind": "ready"})

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
        if args.grids and grids >= args.grids:
            break
        if not got:
            time.sleep(0.02)
    emit({"kind": "done", "grids": grids})


if __name__ == "__main__":
    main()
