"""An independent Foxglove WebSocket client for tests/it/view.rs (the `websockets`
package, the protocol written out here, not the SDK isochron uses): connects with
subprotocol foxglove.sdk.v1 (the name the `foxglove` crate gives
foxglove.websocket.v1 since it was renamed; same messages), reads serverInfo and the advertised channels, subscribes to one
topic and counts the binary message-data frames for it.

usage: python3 ws_client.py URL TOPIC COUNT TIMEOUT_S
prints one JSON object: server name, advertised topics with schema names, and the
messages received on TOPIC (count, size of the first).
"""

import asyncio
import json
import struct
import sys

import websockets


async def run(url: str, topic: str, want: int, timeout: float) -> dict:
    out = {"server": None, "channels": {}, "received": 0, "first_bytes": None}
    async with websockets.connect(
        url, subprotocols=["foxglove.sdk.v1"], max_size=None
    ) as ws:
        out["subprotocol"] = ws.subprotocol
        subscribed = False
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while out["received"] < want:
            left = deadline - loop.time()
            if left <= 0:
                break
            try:
                msg = await asyncio.wait_for(ws.recv(), left)
            except asyncio.TimeoutError:
                break
            if isinstance(msg, str):
                m = json.loads(msg)
                if m.get("op") == "serverInfo":
                    out["server"] = m.get("name")
                elif m.get("op") == "advertise":
                    for ch in m["channels"]:
                        out["channels"][ch["topic"]] = {
                            "id": ch["id"],
                            "schema": ch.get("schemaName"),
                            "encoding": ch.get("encoding"),
                        }
                    if not subscribed and topic in out["channels"]:
                        cid = out["channels"][topic]["id"]
                        await ws.send(
                            json.dumps(
                                {
                                    "op": "subscribe",
                                    "subscriptions": [{"id": 7, "channelId": cid}],
                                }
                            )
                        )
                        subscribed = True
            else:
                # Message data: opcode 1, subscription id u32, log time u64, payload.
                if len(msg) >= 13 and msg[0] == 1:
                    (sub,) = struct.unpack_from("<I", msg, 1)
                    if sub == 7:
                        out["received"] += 1
                        if out["first_bytes"] is None:
                            out["first_bytes"] = len(msg) - 13
    return out


def main() -> int:
    url, topic, want, timeout = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
    print(json.dumps(asyncio.run(run(url, topic, want, timeout))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
