#!/usr/bin/env python3
"""An independent ROS 2 client of isochron's planning services.

Eclipse Cyclone DDS from Python (`cyclonedds` on PyPI) and nothing of isochron or
ROS: the types are declared here (with ros2_dds.py) from ros/isochron_msgs/srv/PlanOffline.srv,
PlanNow.srv and PlanGraph.srv with their DDS names (`isochron_msgs::srv::dds_::PlanNow_Request_`,
..._Response_), on the topics ROS 2 gives a service `/s`: `rq/sRequest` and
`rr/sReply`. As rmw_cyclonedds does, each request and reply starts with the
client's id (8 bytes) and a sequence number (8 bytes); the reply carrying our id
and one of our sequence numbers is ours. The request is sent again every half
second until a reply comes (discovery may not have matched the first one).

Prints one JSON line: {"kind": "reply", ...fields} with costs as numbers, "inf",
or null (NaN), or {"kind": "timeout"}. DDS stays on the loopback interface, as in
costmap_listener.py.

With --poll N, it is a robot asking every half second: once the service is
matched, it sends N requests 0.5 s apart (each once, with its own sequence
number, as a ROS 2 client's async_send_request), waits --timeout seconds after
the last, and prints {"kind": "poll", "sent": N, "latency_ms": [the reply's
latency of each request, or null if none came], "statuses": {status: count}}.

Usage: plan_client.py --domain D --service /isochron/plan_now [--poll N] now ROUTE [ROUTE...]
       plan_client.py --domain D --service /isochron/plan_offline offline ROUTE
              START_MINUTE END_MINUTE STEP_MIN [WEEKDAY]
       plan_client.py --domain D --service /isochron/plan_graph [--poll N] graph FROM TO
              START_MINUTE END_MINUTE STEP_MIN [WEEKDAY]
"""

import argparse
import math
import random
import time

from ros2_dds import absolute, configure, emit, reliable_qos, ros_type


def cost(v):
    if math.isnan(v):
        return None
    if math.isinf(v):
        return "inf"
    return v


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--domain", type=int, required=True)
    parser.add_argument("--service", required=True)
    parser.add_argument("--timeout", type=float, default=20.0)
    parser.add_argument("--poll", type=int, default=0)
    parser.add_argument("kind", choices=["offline", "now", "graph"])
    parser.add_argument("args", nargs="+")
    args = parser.parse_args()
    configure()

    from cyclonedds.domain import DomainParticipant
    from cyclonedds.idl.types import float64, int64, sequence, uint8, uint16, uint64
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    CostPoint = ros_type("isochron_msgs/msg/CostPoint", minute=uint16, cost=float64)

    Window = ros_type("isochron_msgs/msg/Window", start_minute=uint16, end_minute=uint16, cost=float64)

    RouteCost = ros_type(
        "isochron_msgs/msg/RouteCost",
        route=str, cost2=float64, cost1=float64, short_term=float64, infinite=bool, estimated=bool,
        no_long_term=bool,
    )

    def service_type(name, **fields):
        """A request or reply: rmw_cyclonedds's header (client id, sequence number),
        then the .srv fields."""
        return ros_type(name, client=uint64, seq=int64, **fields)

    PlanOfflineRequest = service_type(
        "isochron_msgs/srv/PlanOffline_Request",
        route=str, start_minute=uint16, end_minute=uint16, step_min=uint16, weekday=uint8,
    )

    PlanOfflineResponse = service_type(
        "isochron_msgs/srv/PlanOffline_Response",
        status=uint8, message=str, windows=sequence[Window], curve=sequence[CostPoint], infinite=bool,
    )

    PlanNowRequest = service_type("isochron_msgs/srv/PlanNow_Request", routes=sequence[str])

    PlanNowResponse = service_type(
        "isochron_msgs/srv/PlanNow_Response",
        status=uint8, message=str, t_star=uint16, routes=sequence[RouteCost],
    )

    GraphPath = ros_type(
        "isochron_msgs/msg/GraphPath",
        departure_minute=uint16, nodes=sequence[uint16], edges=sequence[uint16], cost=float64,
        activity_cost=float64, length_m=float64, duration_s=float64, unknown_edges=uint16,
    )

    PlanGraphRequest = service_type(
        "isochron_msgs/srv/PlanGraph_Request",
        from_node=uint16, to_node=uint16, start_minute=uint16, end_minute=uint16, step_min=uint16,
        weekday=uint8,
    )

    PlanGraphResponse = service_type(
        "isochron_msgs/srv/PlanGraph_Response",
        status=uint8, message=str, windows=sequence[Window], window_paths=sequence[GraphPath],
        curve=sequence[CostPoint], best=GraphPath, baseline=GraphPath,
    )

    def graph_path(p):
        return {
            "departure_minute": p.departure_minute, "nodes": list(p.nodes), "edges": list(p.edges),
            "cost": cost(p.cost), "activity_cost": cost(p.activity_cost),
            "length_m": cost(p.length_m), "duration_s": cost(p.duration_s),
            "unknown_edges": p.unknown_edges,
        }

    client = random.getrandbits(63)
    if args.kind == "graph":
        start_node, goal, start, end, step = map(int, args.args[0:5])
        weekday = int(args.args[5]) if len(args.args) > 5 else 7
        req_type, resp_type = PlanGraphRequest, PlanGraphResponse

        def request(seq):
            return PlanGraphRequest(client, seq, start_node, goal, start, end, step, weekday)

        def reply_json(r):
            return {
                "status": r.status,
                "message": r.message,
                "windows": [
                    {"start_minute": w.start_minute, "end_minute": w.end_minute, "cost": cost(w.cost)}
                    for w in r.windows
                ],
                "window_paths": [graph_path(p) for p in r.window_paths],
                "best": graph_path(r.best),
                "baseline": graph_path(r.baseline),
            }
    elif args.kind == "offline":
        route, start, end, step = args.args[0], *map(int, args.args[1:4])
        weekday = int(args.args[4]) if len(args.args) > 4 else 7
        req_type, resp_type = PlanOfflineRequest, PlanOfflineResponse

        def request(seq):
            return PlanOfflineRequest(client, seq, route, start, end, step, weekday)

        def reply_json(r):
            return {
                "status": r.status,
                "message": r.message,
                "windows": [
                    {"start_minute": w.start_minute, "end_minute": w.end_minute, "cost": cost(w.cost)}
                    for w in r.windows
                ],
                "curve": [{"minute": p.minute, "cost": cost(p.cost)} for p in r.curve],
                "infinite": r.infinite,
            }
    else:
        req_type, resp_type = PlanNowRequest, PlanNowResponse

        def request(seq):
            return PlanNowRequest(client, seq, list(args.args))

        def reply_json(r):
            return {
                "status": r.status,
                "message": r.message,
                "t_star": r.t_star,
                "routes": [
                    {
                        "route": x.route,
                        "cost2": cost(x.cost2),
                        "cost1": cost(x.cost1),
                        "short_term": cost(x.short_term),
                        "infinite": x.infinite,
                        "estimated": x.estimated,
                        "no_long_term": x.no_long_term,
                    }
                    for x in r.routes
                ],
            }

    qos = reliable_qos(latched=False, depth=10)
    participant = DomainParticipant(args.domain)
    name = absolute(args.service)
    writer = DataWriter(participant, Topic(participant, "rq" + name + "Request", req_type), qos=qos)
    reader = DataReader(participant, Topic(participant, "rr" + name + "Reply", resp_type), qos=qos)

    if args.poll:
        poll(args, writer, reader, request, client)
        return
    sent = set()
    end_at = time.monotonic() + args.timeout
    next_send = 0.0
    seq = 0
    while time.monotonic() < end_at:
        if time.monotonic() >= next_send:
            seq += 1
            sent.add(seq)
            writer.write(request(seq))
            next_send = time.monotonic() + 0.5
        for r in reader.take(N=16):
            if r.client == client and r.seq in sent:
                emit({"kind": "reply", **reply_json(r)})
                return
        time.sleep(0.02)
    emit({"kind": "timeout"})


def poll(args, writer, reader, request, client):
    """--poll: args.poll requests 0.5 s apart, each sent once; their latencies."""
    end = time.monotonic() + 30
    while not (writer.get_matched_subscriptions() and reader.get_matched_publications()):
        if time.monotonic() > end:
            emit({"kind": "timeout"})
            return
        time.sleep(0.05)
    time.sleep(0.5)  # the bridge's side of the match
    sent_at, latency, statuses = {}, {}, {}
    start = time.monotonic()
    last = start + (args.poll - 1) * 0.5
    while time.monotonic() < last + args.timeout and len(latency) < args.poll:
        due = int((time.monotonic() - start) / 0.5) + 1
        for seq in range(len(sent_at) + 1, min(due, args.poll) + 1):
            sent_at[seq] = time.monotonic()
            writer.write(request(seq))
        for r in reader.take(N=64):
            if r.client == client and r.seq in sent_at and r.seq not in latency:
                latency[r.seq] = round((time.monotonic() - sent_at[r.seq]) * 1000.0, 1)
                statuses[str(r.status)] = statuses.get(str(r.status), 0) + 1
        time.sleep(0.005)
    emit({
        "kind": "poll",
        "sent": len(sent_at),
        "latency_ms": [latency.get(seq) for seq in range(1, args.poll + 1)],
        "statuses": statuses,
    })


if __name__ == "__main__":
    main()
