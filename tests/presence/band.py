"""An independent reader of the presence band and the cost map in an isochron
recording, for tests/it/presence.rs: opens the MCAP file with the `mcap` package
and decodes its protobuf messages with `mcap-protobuf-support` (the schemas the
recording embeds, not isochron's code), then prints one JSON object per second:

    {"t": ns, "present": [block, ...], "costs": [cost of each asked cell]}

`present` lists the blocks of `/<camera>/activity` whose `present` field is at
least 0.5; `costs` the `cost` of `/costmap` at the cells asked for (`-1` where the
recording has no cost map for that second).

usage: python3 band.py FILE.mcap CAMERA [COLUMN,ROW ...]
"""

import json
import struct
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def field(grid, name):
    for f in grid.fields:
        if f.name == name:
            return f
    raise SystemExit(f"grid {grid.frame_id} has no field {name!r}: {[f.name for f in grid.fields]}")


def cells(grid, name, fmt):
    """The values of field `name` of every cell, row-major."""
    f = field(grid, name)
    size = struct.calcsize(fmt)
    data = bytes(grid.data)
    rows = len(data) // grid.row_stride
    out = []
    for r in range(rows):
        for c in range(grid.column_count):
            at = r * grid.row_stride + c * grid.cell_stride + f.offset
            out.append(struct.unpack_from(fmt, data, at)[0])
    return out


def main() -> int:
    path, camera = sys.argv[1], sys.argv[2]
    asked = [tuple(int(v) for v in a.split(",")) for a in sys.argv[3:]]
    seconds = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, channel, message, grid in reader.iter_decoded_messages(
            topics=[f"/{camera}/activity", "/costmap"]
        ):
            t = grid.timestamp.seconds * 1_000_000_000 + grid.timestamp.nanos
            entry = seconds.setdefault(t, {"t": t, "present": [], "costs": [-1] * len(asked)})
            if channel.topic == "/costmap":
                cost = cells(grid, "cost", "<b")
                entry["costs"] = [cost[row * grid.column_count + col] for col, row in asked]
            else:
                present = cells(grid, "present", "<f")
                entry["present"] = [k for k, v in enumerate(present) if v >= 0.5]
    for t in sorted(seconds):
        print(json.dumps(seconds[t]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
