#!/usr/bin/env python3
"""A hostile client of isochron's PlanNow service: garbage and floods.

Eclipse Cyclone DDS from Python (`cyclonedds` on PyPI) and nothing of isochron,
on the topics and type name of /isochron/plan_now (see plan_client.py), in
rmw_cyclonedds's layout (client id and sequence number before the fields). The
request types here are forged: their fields are raw bytes, so the requests can
be what no ROS 2 client would send.

garbage: sends, once the service is matched,
  * "no_nul": a request whose one route name is the 4 bytes "dock" with a length
    of 4 and no NUL (a CDR string's length counts its NUL);
  * "count": a request claiming 1 000 000 route names in 8 bytes;
  * "short": 3 bytes, too short for the header (from a second participant:
    another forged type on the same topic), which cannot be answered;
  and prints {"kind": "garbage", "replies": {"no_nul": {"status", "message"} or
  null, "count": ...}} after waiting --wait seconds for the replies.

flood N SECONDS ROUTE: sends N well-formed requests for route ROUTE in SECONDS, each
with its own sequence number, waits --wait seconds more, and prints {"kind":
"flood", "sent": N, "replies": distinct sequence numbers answered, "statuses":
{status: count}, "seconds": how long sending took}.

DDS stays on the loopback interface, as in costmap_listener.py.

With --service /isochron/plan_graph (a name ending in plan_graph), flood sends
PlanGraph requests instead, ROUTE being "FROM,TO,START_MINUTE,END_MINUTE,STEP_MIN,WEEKDAY".

Usage: plan_attacker.py --domain D --service /isochron/plan_now [--wait S] garbage
       plan_attacker.py --domain D --service /isochron/plan_now [--wait S] flood N SECONDS ROUTE
       plan_attacker.py --domain D --service /isochron/plan_graph [--wait S] flood N SECONDS
              FROM,TO,START,END,STEP,WEEKDAY
"""

import argparse
import random
import time

from ros2_dds import absolute, configure, emit, reliable_qos, ros_type


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--domain", type=int, required=True)
    parser.add_argument("--service", required=True)
    parser.add_argument("--wait", type=float, default=10.0)
    parser.add_argument("mode", choices=["garbage", "flood"])
    parser.add_argument("args", nargs="*")
    args = parser.parse_args()
    configure()

    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.idl.types import array, float64, int64, sequence, uint8, uint16, uint64
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    RouteCost = ros_type(
        "isochron_msgs/msg/RouteCost",
        route=str, cost2=float64, cost1=float64, short_term=float64, infinite=bool, estimated=bool,
        no_long_term=bool,
    )
    Reply = ros_type(
        "isochron_msgs/srv/PlanNow_Response",
        client=uint64, seq=int64, status=uint8, message=str, t_star=uint16, routes=sequence[RouteCost],
    )
    graph = args.service.endswith("plan_graph")
    if graph:
        CostPoint = ros_type("isochron_msgs/msg/CostPoint", minute=uint16, cost=float64)
        Window = ros_type(
            "isochron_msgs/msg/Window", start_minute=uint16, end_minute=uint16, cost=float64
        )
        GraphPath = ros_type(
            "isochron_msgs/msg/GraphPath",
            departure_minute=uint16, nodes=sequence[uint16], edges=sequence[uint16],
            cost=float64, activity_cost=float64, length_m=float64, duration_s=float64,
            unknown_edges=uint16,
        )
        Reply = ros_type(
            "isochron_msgs/srv/PlanGraph_Response",
            client=uint64, seq=int64, status=uint8, message=str, windows=sequence[Window],
            window_paths=sequence[GraphPath], curve=sequence[CostPoint], best=GraphPath,
            baseline=GraphPath,
        )
    name = absolute(args.service)
    # Every request is kept until the bridge has it: what the bridge drops, it drops.
    qos = Qos(
        Policy.Reliability.Reliable(duration(seconds=5)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(4096),
        Policy.DataRepresentation(use_cdrv0_representation=True),
    )
    participant = DomainParticipant(args.domain)
    reader = DataReader(
        participant, Topic(participant, "rr" + name + "Reply", Reply), qos=reliable_qos(False, 4096)
    )
    client = random.getrandbits(63)

    def wait_matched(writer):
        end = time.monotonic() + 30
        while time.monotonic() < end:
            if writer.get_matched_subscriptions() and reader.get_matched_publications():
                time.sleep(0.5)  # the bridge's side of the match
                return
            time.sleep(0.05)
        raise SystemExit("the service never appeared")

    def replies(until):
        got = {}
        while time.monotonic() < until:
            for r in reader.take(N=256):
                if r.client == client:
                    got[r.seq] = r
            time.sleep(0.02)
        return got

    if args.mode == "garbage":
        body_no_nul = bytes([1, 0, 0, 0, 4, 0, 0, 0]) + b"dock"
        body_count = (1_000_000).to_bytes(4, "little") + bytes([2, 0, 0, 0, 0x61, 0])
        Forged = ros_type(
            "isochron_msgs/srv/PlanNow_Request",
            client=uint64, seq=int64, body=array[uint8, len(body_no_nul)],
        )
        writer = DataWriter(participant, Topic(participant, "rq" + name + "Request", Forged), qos=qos)
        wait_matched(writer)
        writer.write(Forged(client, 1, list(body_no_nul)))
        writer.write(Forged(client, 2, list(body_count.ljust(len(body_no_nul), b"\0"))))
        # Too short for a header, from a participant of its own (another type).
        other = DomainParticipant(args.domain)
        Short = ros_type("isochron_msgs/srv/PlanNow_Request", body=array[uint8, 3])
        short = DataWriter(other, Topic(other, "rq" + name + "Request", Short), qos=qos)
        end = time.monotonic() + 30
        while not short.get_matched_subscriptions() and time.monotonic() < end:
            time.sleep(0.05)
        time.sleep(0.5)
        short.write(Short([1, 2, 3]))
        got = replies(time.monotonic() + args.wait)

        def one(seq):
            r = got.get(seq)
            return None if r is None else {"status": r.status, "message": r.message}

        emit({"kind": "garbage", "replies": {"no_nul": one(1), "count": one(2)}})
        return

    n, seconds, route = int(args.args[0]), float(args.args[1]), args.args[2]
    if graph:
        Request = ros_type(
            "isochron_msgs/srv/PlanGraph_Request",
            client=uint64, seq=int64, from_node=uint16, to_node=uint16, start_minute=uint16,
            end_minute=uint16, step_min=uint16, weekday=uint8,
        )
        fields = [int(f) for f in route.split(",")]

        def request(seq):
            return Request(client, seq, *fields)
    else:
        Request = ros_type(
            "isochron_msgs/srv/PlanNow_Request", client=uint64, seq=int64, routes=sequence[str]
        )

        def request(seq):
            return Request(client, seq, [route])
    writer = DataWriter(participant, Topic(participant, "rq" + name + "Request", Request), qos=qos)
    wait_matched(writer)
    start = time.monotonic()
    got = {}
    for k in range(n):
        writer.write(request(k + 1))
        for r in reader.take(N=256):
            if r.client == client:
                got[r.seq] = r
        pause = start + (k + 1) * seconds / n - time.monotonic()
        if pause > 0:
            time.sleep(pause)
    took = time.monotonic() - start
    got.update(replies(time.monotonic() + args.wait))
    statuses = {}
    for r in got.values():
        statuses[str(r.status)] = statuses.get(str(r.status), 0) + 1
    emit({"kind": "flood", "sent": n, "replies": len(got), "statuses": statuses, "seconds": took})


if __name__ == "__main__":
    main()
