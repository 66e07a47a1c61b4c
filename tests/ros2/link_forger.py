#!/usr/bin/env python3
"""An attacker on a site's network: an unauthenticated Eclipse Cyclone DDS
participant that writes forged isochron-link messages.

Eclipse Cyclone DDS from Python (`cyclonedds` on PyPI) and nothing of isochron:
the message types are read from ros/isochron_msgs/msg/*.msg (so they follow the
repository's messages), with their ROS 2 DDS names
(`isochron_msgs::msg::dds_::Activity_`), on the link's topics
`rt<namespace>/<camera>/<stream>`.

What it forges (--forge):
  huge-grid    Activity whose grid is 0xFFFFFFFF x 0xFFFFFFFF blocks, with one block
  empty-grid   Activity of a 65 536 x 65 536 grid with no blocks
  other-grid   a well-formed Activity of a 160x128 frame in 16-px blocks (smaller
               than the test camera's, so a reader's sample bound admits it)
  evil         a well-formed Activity of the test camera (320x240, 16 px) from
               box "evil", every block at s1 = 1
  events       Event records that end before they start, or start before 1970
  detections   Detections of two people in the middle of the frame
  status       each stage's Status with a report time of 2^62 and pid 1

It writes for --seconds at 10 Hz, then prints {"kind": "sent", "count": N,
"matched": M} (M: readers its writers matched). DDS stays on the loopback
interface (as costmap_listener.py), unless --config gives a Cyclone DDS XML
(a network namespace's address, or a security configuration).

Usage: link_forger.py --domain D --forge KIND [--camera cam01]
       [--namespace /isochron/link] [--layout-version V] [--seconds S]
"""

import argparse
import os
import re
import time
import types
from dataclasses import dataclass
from pathlib import Path

from ros2_dds import configure, emit, reliable_qos

MSG_DIR = Path(__file__).resolve().parents[2] / "ros/isochron_msgs/msg"
MAGIC = int.from_bytes(b"ISOC", "little")
# Bytes of one payload element in shared memory (wire.rs): BlockActivity, u32, Detection.
ELEMENT_SIZE = {"activity": 36, "events": 4, "detections": 232}
STREAM = {"activity": 3, "events": 4, "detections": 5}


def load_types():
    """Every message of ros/isochron_msgs/msg as a Cyclone DDS IDL struct, and
    `build(name, **values)`: a message with `values`, every other field zero."""
    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl import types as t

    primitive = {
        "bool": bool, "uint8": t.uint8, "int8": t.int8, "uint16": t.uint16,
        "int16": t.int16, "uint32": t.uint32, "int32": t.int32, "uint64": t.uint64,
        "int64": t.int64, "float32": t.float32, "float64": t.float64, "string": str,
    }
    defs = {}
    for path in sorted(MSG_DIR.glob("*.msg")):
        fields = []
        for line in path.read_text().splitlines():
            line = line.split("#", 1)[0].strip()
            if line:
                kind, name = line.split()[:2]
                m = re.fullmatch(r"(\w+)(\[(\d*)\])?", kind)
                fields.append((name, m.group(1), m.group(2) is not None, m.group(3)))
        defs[path.stem] = fields
    made = {}

    def make(name):
        if name not in made:
            def field_type(base, is_array, size):
                inner = primitive[base] if base in primitive else make(base)
                if not is_array:
                    return inner
                return t.array[inner, int(size)] if size else t.sequence[inner]

            fields = {n: field_type(b, a, s) for n, b, a, s in defs[name]}
            cls = types.new_class(
                name,
                (IdlStruct,),
                {"typename": f"isochron_msgs::msg::dds_::{name}_"},
                lambda ns: ns["__annotations__"].update(fields),
            )
            made[name] = dataclass(cls)
        return made[name]

    def zero(base):
        if base in defs:
            return build(base)
        return {"string": "", "bool": False, "float32": 0.0, "float64": 0.0}.get(base, 0)

    def build(name, **values):
        out = {}
        for field, base, is_array, size in defs[name]:
            if field in values:
                out[field] = values[field]
            elif is_array:
                out[field] = [zero(base) for _ in range(int(size))] if size else []
            else:
                out[field] = zero(base)
        return make(name)(**out)

    return {name: make(name) for name in defs}, build


def camera_bytes(camera):
    return list(camera.encode().ljust(24, b"\0"))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--domain", type=int, required=True)
    parser.add_argument("--forge", required=True, choices=[
        "huge-grid", "empty-grid", "other-grid", "evil", "events", "detections", "status",
    ])
    parser.add_argument("--camera", default="cam01")
    parser.add_argument("--namespace", default="/isochron/link")
    parser.add_argument("--layout-version", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--box", default="evil")
    parser.add_argument("--config", help="a Cyclone DDS XML to use instead of loopback only")
    args = parser.parse_args()
    if args.config:
        os.environ["CYCLONEDDS_URI"] = args.config
    else:
        configure()

    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    T, build = load_types()
    now_ns = time.time_ns()

    def preamble(stream, seq, payload_len, **more):
        return build("Preamble", magic=MAGIC, layout_version=args.layout_version,
            stream=STREAM[stream], camera=camera_bytes(args.camera), sequence=seq,
            capture_time_ns=now_ns + seq * 1_000_000_000, origin_wall_ns=time.time_ns(),
            payload_len=payload_len, element_size=ELEMENT_SIZE[stream], **more,
        )

    def activity(seq, frame, block_px, grid, blocks, s1=0.0):
        header = build("ActivityHeader", preamble=preamble("activity", seq, blocks),
            grid_w=grid[0], grid_h=grid[1], block_px=block_px,
            frame_width=frame[0], frame_height=frame[1], t_star=660, model_days=10,
            frames=10, frame_rate=10.0,
        )
        block = build("BlockActivity", s1=s1)
        return build("Activity", box_id=args.box, header=header, blocks=[block] * blocks)

    def event(seq, phase, start_ns, end_ns):
        header = build("EventHeader", preamble=preamble("events", seq, 1), event_id=seq,
            zone=list(b"door".ljust(32, b"\0")), kind=2, phase=phase,
            start_ns=start_ns, end_ns=end_ns, peak=5.0, threshold=1.0,
        )
        return build("Event", box_id=args.box, header=header, blocks=[3])

    def detections(seq):
        header = build("DetectionHeader", preamble=preamble("detections", seq, 2), event_id=seq,
            source_index=seq,
        )
        people = [
            build("Detection", x=x, y=100.0, w=20.0, h=60.0, score=2.0, class_id=0)
            for x in (120.0, 180.0)
        ]
        return build("Detections", box_id=args.box, header=header, detections=people)

    def status(stage):
        s = build("StageStatus", magic=MAGIC, layout_version=args.layout_version,
            camera=camera_bytes(args.camera), stage=list(stage.encode().ljust(16, b"\0")),
            pid=1, rate_in=10.0, rate_out=10.0, started_wall_ns=1, report_wall_ns=1 << 62,
        )
        return build("Status", box_id=args.box, status=s)

    stream, msg = {
        "huge-grid": ("activity", "Activity"), "empty-grid": ("activity", "Activity"),
        "other-grid": ("activity", "Activity"), "evil": ("activity", "Activity"),
        "events": ("events", "Event"), "detections": ("detections", "Detections"),
        "status": ("status", "Status"),
    }[args.forge]

    def forged(seq):
        if args.forge == "huge-grid":
            return [activity(seq, (0xFFFFFFFF,) * 2, 1, (0xFFFFFFFF,) * 2, 1)]
        if args.forge == "empty-grid":
            return [activity(seq, (65536 * 16,) * 2, 16, (65536,) * 2, 0)]
        if args.forge == "other-grid":
            return [activity(seq, (160, 128), 16, (10, 8), 80, s1=1.0)]
        if args.forge == "evil":
            return [activity(seq, (320, 240), 16, (20, 15), 300, s1=1.0)]
        if args.forge == "events":
            return [
                event(2 * seq, 2, now_ns, now_ns - 3_600_000_000_000),
                event(2 * seq + 1, 1, -5_000_000_000, 0),
            ]
        if args.forge == "detections":
            return [detections(seq)]
        return [status(stage) for stage in ("capture", "motion", "cascade", "gate")]

    participant = DomainParticipant(args.domain)
    topic = Topic(participant, f"rt{args.namespace}/{args.camera}/{stream}", T[msg])
    writer = DataWriter(participant, topic, qos=reliable_qos(latched=False, depth=64))
    sent, matched, seq = 0, 0, 0
    end_at = time.monotonic() + args.seconds
    while time.monotonic() < end_at:
        matched = max(matched, len(writer.get_matched_subscriptions()))
        for sample in forged(seq):
            writer.write(sample)
            sent += 1
        seq += 1
        time.sleep(0.1)
    emit({"kind": "sent", "count": sent, "matched": matched})


if __name__ == "__main__":
    main()
