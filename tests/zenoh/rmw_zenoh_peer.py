"""A robot on rmw_zenoh, from PyPI: the peer tests/it/zenoh.rs runs against the
costmap bridge's Zenoh output.

Two implementations isochron did not write read what the bridge sends:

* zenoh-ros2-sdk (a third-party implementation of rmw_zenoh's format: key
  expressions with type hashes it computes from the .msg files, attachments,
  liveliness tokens, service queries) subscribes to the topics and calls the
  planning services;
* eclipse-zenoh itself checks the bytes: every data key expression, the
  attachment of each sample (sequence number, timestamp, GID), the CDR
  encapsulation header, the liveliness tokens of the graph, and — as
  rmw_zenoh's transient-local subscriptions do — an advanced subscriber that
  joins late and gets the latched grid from the publisher's cache.

Commands (one JSON object per line on stdout, as tests/ros2/rclpy_peer.py):

  router --listen ENDPOINT               a Zenoh router, until killed
  listen --router PORT --domain D ...    subscribe, report messages, then tokens
  late --router PORT --domain D --topic T   the late joiner
  plan --router PORT --domain D CALLS    call the services (CALLS: JSON list)
  route-server --router PORT --domain D  serve nav2_msgs/srv/DynamicEdges at
                                         /route_server/DynamicEdgesScorer/adjust_edges
                                         as nav2_route's scorer keeps it; one
                                         "adjust_edges" line per request, in the
                                         format of tests/ros2/rclpy_peer.py route-server;
                                         with --grid, a "first_grid" line too
"""

import argparse
import json
import os
import struct
import sys
import threading
import time

import zenoh
import zenoh.ext

from zenoh_ros2_sdk import ROS2ServiceClient, ROS2ServiceServer, ROS2Subscriber, get_registry

LOCK = threading.Lock()


def emit(obj):
    with LOCK:
        print(json.dumps(obj), flush=True)


def stamp(header):
    return [header.stamp.sec, header.stamp.nanosec]


def pose(p):
    o = p.orientation
    return [p.position.x, p.position.y, p.position.z, o.x, o.y, o.z, o.w]


def grid_json(kind, msg):
    info = msg.info
    return {
        "kind": kind, "frame_id": msg.header.frame_id, "stamp": stamp(msg.header),
        "width": info.width, "height": info.height, "resolution": info.resolution,
        "origin": pose(info.origin), "data": [int(v) for v in msg.data],
    }


def router(args):
    config = zenoh.Config()
    config.insert_json5("mode", '"router"')
    config.insert_json5("listen/endpoints", json.dumps([args.listen]))
    config.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(config) as session:
        emit({"kind": "router", "zid": str(session.zid())})
        while True:
            time.sleep(1)


def session(args):
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{args.router}"]))
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)


def sdk_subscribe(args, topic, msg_type, on_msg):
    return ROS2Subscriber(
        topic=topic, msg_type=msg_type, callback=on_msg, domain_id=args.domain,
        router_ip="127.0.0.1", router_port=args.router,
    )


def listen(args):
    """The SDK's subscribers on every topic; eclipse-zenoh on the raw bytes."""
    subs = []
    for topic, ty, kind in [
        (args.topic, "nav_msgs/msg/OccupancyGrid", "grid"),
        (args.topic + "_updates", "map_msgs/msg/OccupancyGridUpdate", "update"),
        ("/isochron/people", "geometry_msgs/msg/PoseArray", "people"),
        ("/isochron/markers", "visualization_msgs/msg/MarkerArray", "markers"),
        ("/isochron/speed_filter_info", "nav2_msgs/msg/CostmapFilterInfo", "filter_info"),
        ("/isochron/speed_mask", "nav_msgs/msg/OccupancyGrid", "speed_mask"),
        ("/isochron/activity_forecast", "nav_msgs/msg/OccupancyGrid", "forecast"),
    ]:
        def on_msg(msg, kind=kind):
            if kind in ("grid", "speed_mask", "forecast"):
                emit(grid_json(kind, msg))
            elif kind == "update":
                emit({"kind": kind, "stamp": stamp(msg.header), "x": msg.x, "y": msg.y,
                      "width": msg.width, "height": msg.height,
                      "data": [int(v) for v in msg.data]})
            elif kind == "people":
                emit({"kind": kind, "frame_id": msg.header.frame_id,
                      "stamp": stamp(msg.header), "poses": [pose(p) for p in msg.poses]})
            elif kind == "markers":
                emit({"kind": kind, "markers": [m.ns for m in msg.markers]})
            else:
                emit({"kind": kind, "type": msg.type,
                      "filter_mask_topic": msg.filter_mask_topic,
                      "base": msg.base, "multiplier": msg.multiplier})
        subs.append(sdk_subscribe(args, topic, ty, on_msg))

    raw = session(args)
    seen = {}

    def on_raw(sample):
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        att = sample.attachment.to_bytes() if sample.attachment is not None else b""
        entry = {"kind": "raw", "key": key, "attachment_len": len(att),
                 "encapsulation": payload[:4].hex()}
        if len(att) >= 17:
            seq, ts = struct.unpack("<qq", att[:16])
            entry.update(seq=seq, timestamp_ns=ts, gid_len=att[16], gid=att[17:].hex())
        n = seen.get(key, 0)
        seen[key] = n + 1
        if n < 2:
            emit(entry)

    raw_sub = raw.declare_subscriber(f"{args.domain}/**", on_raw)

    emit({"kind": "ready", "zenoh_ros2_sdk": "0.1.8"})
    time.sleep(args.timeout)
    tokens = [str(r.ok.key_expr) for r in raw.liveliness().get(f"@ros2_lv/{args.domain}/**")
              if r.ok is not None]
    emit({"kind": "tokens", "tokens": sorted(tokens)})
    raw_sub.undeclare()
    emit({"kind": "done"})


def late(args):
    """rmw_zenoh's transient-local subscription: an advanced subscriber that
    detects the publisher and queries its cache; on the grid and on the speed
    filter's info (published once, when the bridge starts)."""
    z = session(args)
    keys = {
        "late_grid": f"{args.domain}/{args.topic.strip('/')}/"
                     f"nav_msgs::msg::dds_::OccupancyGrid_/{args.hash}",
        "late_filter_info": f"{args.domain}/isochron/speed_filter_info/"
                            "nav2_msgs::msg::dds_::CostmapFilterInfo_/*",
    }
    t0 = time.monotonic()
    pending = set(keys)
    done = threading.Event()
    subs = []
    for kind, key in keys.items():
        def on_sample(sample, kind=kind):
            with LOCK:
                if kind not in pending:
                    return
                pending.discard(kind)
                if not pending:
                    done.set()
            payload = sample.payload.to_bytes()
            emit({"kind": kind, "after_s": time.monotonic() - t0, "key": str(sample.key_expr),
                  "bytes": len(payload), "encapsulation": payload[:4].hex(),
                  "text": payload.decode("latin-1")})
        subs.append(zenoh.ext.declare_advanced_subscriber(
            z, key, on_sample,
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            recovery=zenoh.ext.RecoveryConfig(heartbeat=True),
            subscriber_detection=True,
        ))
    emit({"kind": "ready"})
    done.wait(args.timeout)
    if not done.is_set():
        emit({"kind": "timeout", "missing": sorted(pending)})
    for sub in subs:
        sub.undeclare()


def plan(args):
    calls = json.loads(args.calls)
    clients = {}
    for call in calls:
        service = call["service"]
        if service not in clients:
            ty = "isochron_msgs/srv/PlanNow" if service.endswith("plan_now") else \
                "isochron_msgs/srv/PlanGraph" if service.endswith("plan_graph") else \
                "isochron_msgs/srv/PlanOffline"
            clients[service] = ROS2ServiceClient(
                service_name=service, srv_type=ty, domain_id=args.domain,
                router_ip="127.0.0.1", router_port=args.router, timeout=args.call_timeout,
            )
        t0 = time.monotonic()
        r = clients[service].call(**call["request"])
        took = time.monotonic() - t0
        if r is None:
            emit({"kind": "timeout", "service": service, "s": took})
            continue
        out = {"kind": "reply", "service": service, "status": int(r.status),
               "message": r.message, "s": took}
        if hasattr(r, "routes"):
            out["t_star"] = int(r.t_star)
            out["routes"] = [[x.route, x.cost2, bool(x.infinite)] for x in r.routes]
        elif hasattr(r, "baseline"):
            ints = lambda xs: [int(x) for x in xs]  # numpy integers, as the SDK decodes arrays
            out["windows"] = [[int(w.start_minute), int(w.end_minute), float(w.cost)]
                              for w in r.windows]
            out["window_edges"] = [ints(p.edges) for p in r.window_paths]
            out["best"] = {"departure_minute": int(r.best.departure_minute),
                           "nodes": ints(r.best.nodes), "edges": ints(r.best.edges),
                           "cost": float(r.best.cost)}
            out["baseline"] = {"nodes": ints(r.baseline.nodes),
                               "edges": ints(r.baseline.edges), "cost": float(r.baseline.cost)}
        else:
            out["windows"] = [[w.start_minute, w.end_minute, w.cost] for w in r.windows]
        emit(out)


def route_server(args):
    start = time.monotonic()
    closed, costs = set(), {}
    server = None

    def adjust_edges(request):
        ids = lambda xs: [int(x) for x in xs]  # numpy integers, as the SDK decodes arrays
        closed.update(ids(request.closed_edges))
        closed.difference_update(ids(request.opened_edges))
        adjust = [[int(e.edgeid), float(e.cost)] for e in request.adjust_edges]
        for edge, cost in adjust:
            costs[edge] = cost
        emit({"kind": "adjust_edges", "t": round(time.monotonic() - start, 3),
              "closed": ids(request.closed_edges), "opened": ids(request.opened_edges),
              "adjust": adjust,
              "state": {"closed": sorted(closed),
                        "costs": {str(k): v for k, v in sorted(costs.items())}}})
        return server.response_msg_class(success=True)

    # The SDK's type store (rosbags) resolves a .srv's same-package field type
    # `EdgeCost` as nav2_msgs/srv/msg/EdgeCost and finds nothing there: the
    # request failed to decode. Registered under that name too.
    from rosbags.typesys import get_types_from_msg
    from zenoh_ros2_sdk.session import ZenohSession
    with open(os.path.join(args.messages, "nav2_msgs/msg/EdgeCost.msg")) as f:
        edge_cost = f.read()
    ZenohSession.get_instance("127.0.0.1", args.router).store.register(
        get_types_from_msg(edge_cost, "nav2_msgs/srv/msg/EdgeCost"))
    server = ROS2ServiceServer(
        service_name="/route_server/DynamicEdgesScorer/adjust_edges",
        srv_type="nav2_msgs/srv/DynamicEdges", callback=adjust_edges,
        node_name="route_server", domain_id=args.domain, router_ip="127.0.0.1",
        router_port=args.router,
    )
    emit({"kind": "ready", "service": "/route_server/DynamicEdgesScorer/adjust_edges"})
    if args.grid:
        grids = []

        def on_grid(msg):
            if not grids:
                emit({"kind": "first_grid", "t": round(time.monotonic() - start, 3)})
            grids.append(1)
        subscriber = sdk_subscribe(args, args.topic, "nav_msgs/msg/OccupancyGrid", on_grid)
    time.sleep(args.timeout)
    emit({"kind": "done"})


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("command", choices=["router", "listen", "late", "plan", "route-server"])
    parser.add_argument("calls", nargs="?")
    parser.add_argument("--listen")
    parser.add_argument("--router", type=int)
    parser.add_argument("--domain", type=int, default=0)
    parser.add_argument("--topic", default="/isochron/activity_costmap")
    parser.add_argument("--hash", default="")
    parser.add_argument("--grid", action="store_true",
                        help="route-server: also note the first grid on --topic")
    parser.add_argument("--messages", help="a share/ directory with the .msg/.srv files")
    parser.add_argument("--timeout", type=float, default=30)
    parser.add_argument("--call-timeout", type=float, default=5)
    args = parser.parse_args()
    if args.messages:
        get_registry(args.messages)
    {"router": router, "listen": listen, "late": late, "plan": plan,
     "route-server": route_server}[args.command](args)
    # zenoh-ros2-sdk leaves threads that keep the interpreter from exiting.
    sys.stdout.flush()
    os._exit(0)


if __name__ == "__main__":
    sys.exit(main())
