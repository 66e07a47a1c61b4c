"""A Foxglove WebSocket client that stops reading, for tests/it/view.rs: the
`websockets` package over a socket with a 4 KiB receive buffer. It completes the
handshake (subprotocol foxglove.sdk.v1), reads serverInfo and the advertised
channels, subscribes to all of them, and then reads nothing: `websockets` stops
taking bytes from the socket once one message waits, so the server's sends back up.

usage: python3 stalled_client.py URL DEADLINE_S
prints one JSON line as soon as it has subscribed (its local port, the topics),
then watches the socket, still reading nothing, until the server closes it or
DEADLINE_S pass, and prints a second line: whether the server had closed the
connection, after how many seconds, and how many messages it read after that
(or in 10 s, if the server did not close it).
"""

import asyncio
import json
import select
import socket
import sys
import time

import websockets


async def subscribe_to_everything(ws) -> dict:
    """Waits (20 s at most) for the view's advertise, subscribes to every channel
    it names, and returns them, topic -> channel id."""
    topics = {}
    deadline = time.monotonic() + 20
    while not topics and time.monotonic() < deadline:
        msg = await asyncio.wait_for(ws.recv(), 20)
        if isinstance(msg, str):
            m = json.loads(msg)
            if m.get("op") == "advertise":
                for ch in m["channels"]:
                    topics[ch["topic"]] = ch["id"]
    subs = [{"id": k, "channelId": cid} for k, cid in enumerate(topics.values())]
    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
    return topics


def closed_by_server(ws, sock: socket.socket) -> bool:
    """Whether the server has closed (or reset) the connection, found without
    reading from it: reading would make the client a reader again, and the server
    would rightly stop counting it as stalled."""
    if ws.state.name in ("CLOSING", "CLOSED") or sock.fileno() == -1:
        return True
    poller = select.poll()
    poller.register(sock.fileno(), select.POLLRDHUP | select.POLLHUP | select.POLLERR)
    return any(
        ev & (select.POLLRDHUP | select.POLLHUP | select.POLLERR)
        for _, ev in poller.poll(0)
    )


async def wait_until_closed(conns, deadline_s: float) -> list:
    """Polls every connection ((ws, sock) pairs) every 100 ms, reading nothing,
    until the server has closed them all or `deadline_s` pass; per connection, the
    seconds after which it was seen closed, or None."""
    t0 = time.monotonic()
    closed_after = [None] * len(conns)
    while time.monotonic() - t0 < deadline_s:
        for i, (ws, sock) in enumerate(conns):
            if closed_after[i] is None and closed_by_server(ws, sock):
                closed_after[i] = round(time.monotonic() - t0, 2)
        if all(c is not None for c in closed_after):
            break
        await asyncio.sleep(0.1)
    return closed_after


async def run(url: str, deadline_s: float) -> None:
    host, port = url.removeprefix("ws://").rstrip("/").rsplit(":", 1)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    # Before connecting, so the window the server sees stays small.
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect((host, int(port)))
    sock.setblocking(False)
    async with websockets.connect(
        url,
        sock=sock,
        subprotocols=["foxglove.sdk.v1"],
        max_size=None,
        max_queue=1,
        ping_interval=None,
        close_timeout=1,
    ) as ws:
        topics = await subscribe_to_everything(ws)
        print(
            json.dumps(
                {"local_port": sock.getsockname()[1], "subscribed": sorted(topics)}
            ),
            flush=True,
        )
        # Read nothing until the server closes it (or the deadline).
        [closed_after] = await wait_until_closed([(ws, sock)], deadline_s)
        # A server that closed it: what was left in the buffers, then the end. One
        # that did not: messages for as long as one reads (10 s here).
        waiting, closed = 0, False
        end = time.monotonic() + 10
        try:
            while time.monotonic() < end:
                await asyncio.wait_for(ws.recv(), max(end - time.monotonic(), 0.01))
                waiting += 1
        except websockets.ConnectionClosed:
            closed = True
        except (asyncio.TimeoutError, ConnectionError):
            pass
        print(
            json.dumps(
                {"closed": closed, "closed_after_s": closed_after, "waiting": waiting}
            ),
            flush=True,
        )


def main() -> int:
    asyncio.run(run(sys.argv[1], float(sys.argv[2])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
