"""Many Foxglove WebSocket clients that stop reading, for tests/it/view.rs: the
`websockets` package, N connections from one process, each over a socket with a
4 KiB receive buffer. Each completes the handshake (subprotocol foxglove.sdk.v1),
reads serverInfo and the advertised channels, subscribes to all of them, and then
reads nothing (`websockets` stops taking bytes from the socket once one message
waits, so the server's sends back up). A client the server refuses records the
HTTP status it answered with.

usage: python3 stalled_clients.py URL N DEADLINE_S
prints one JSON line once every client has subscribed or been refused
({"subscribed": n, "refused": {status: n}, "failed": [reasons]}), then watches
the subscribed connections, reading nothing, until the server has closed them all
or DEADLINE_S pass, and prints a second line: how many it closed, how many are
still open, and the seconds after which the first and the last were seen closed
({"closed": n, "open": n, "first_closed_s": s, "last_closed_s": s}).
"""

import asyncio
import json
import socket
import sys

import websockets
from websockets.exceptions import InvalidStatus

from stalled_client import subscribe_to_everything, wait_until_closed


async def subscribe(url: str):
    """A connection subscribed to every advertised channel, or why there is none."""
    host, port = url.removeprefix("ws://").rstrip("/").rsplit(":", 1)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    # Before connecting, so the window the server sees stays small.
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.setblocking(False)
    await asyncio.get_running_loop().sock_connect(sock, (host, int(port)))
    try:
        ws = await websockets.connect(
            url,
            sock=sock,
            subprotocols=["foxglove.sdk.v1"],
            max_size=None,
            max_queue=1,
            ping_interval=None,
            close_timeout=1,
            open_timeout=20,
        )
    except InvalidStatus as e:
        sock.close()
        return ("refused", e.response.status_code)
    await subscribe_to_everything(ws)
    return ("subscribed", (ws, sock))


async def run(url: str, n: int, deadline_s: float) -> None:
    results = await asyncio.gather(
        *(subscribe(url) for _ in range(n)), return_exceptions=True
    )
    open_ws, refused, failed = [], {}, []
    for r in results:
        if isinstance(r, BaseException):
            failed.append(repr(r))
        elif r[0] == "refused":
            refused[str(r[1])] = refused.get(str(r[1]), 0) + 1
        else:
            open_ws.append(r[1])
    print(
        json.dumps({"subscribed": len(open_ws), "refused": refused, "failed": failed}),
        flush=True,
    )
    # Read nothing, until the server has closed every one (or the deadline).
    closed_after = [c for c in await wait_until_closed(open_ws, deadline_s) if c is not None]
    print(
        json.dumps(
            {
                "closed": len(closed_after),
                "open": len(open_ws) - len(closed_after),
                "first_closed_s": min(closed_after, default=None),
                "last_closed_s": max(closed_after, default=None),
            }
        ),
        flush=True,
    )


def main() -> int:
    asyncio.run(run(sys.argv[1], int(sys.argv[2]), float(sys.argv[3])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
