#!/usr/bin/python3
"""An IP camera for the tests: GStreamer's RTSP server (gst-rtsp-server, Debian's
gstreamer1.0-rtsp) serving one H.264 or H.265 stream, the way a real camera does.

    /usr/bin/python3 tests/rtsp/camera.py --port 8554 [--file data/vtest.avi]
        [--codec h264|h265] [--size 768x576] [--fps 10] [--user U --password P]
        [--address 127.0.0.1]

Serves rtsp://ADDRESS:PORT/cam (TCP and UDP transports both allowed) and prints
`ready rtsp://ADDRESS:PORT/cam` on stdout once it listens. Without --file it
serves a moving test pattern as a live source; with one, the file's frames at
its own pace (each client from the first frame). With --user/--password it asks
for Basic authentication and answers a wrong one with 401.
"""

import argparse
import signal
import sys

import gi

gi.require_version("Gst", "1.0")
gi.require_version("GstRtspServer", "1.0")
from gi.repository import GLib, Gst, GstRtspServer  # noqa: E402


def pipeline(args):
    width, height = args.size.split("x")
    caps = f"video/x-raw,format=I420,width={width},height={height},framerate={args.fps}/1"
    if args.file:
        source = (
            f'filesrc location="{args.file}" ! decodebin ! videoconvert ! videoscale '
            f"! videorate ! {caps}"
        )
    else:
        source = f"videotestsrc is-live=true pattern=ball ! {caps}"
    # One key frame a second, so a client that joins or rejoins decodes at once.
    if args.codec == "h265":
        encode = (
            f"x265enc tune=zerolatency speed-preset=ultrafast key-int-max={args.fps} "
            "! rtph265pay name=pay0 pt=96 config-interval=1"
        )
    else:
        encode = (
            f"x264enc tune=zerolatency speed-preset=ultrafast key-int-max={args.fps} "
            "! rtph264pay name=pay0 pt=96 config-interval=1"
        )
    return f"( {source} ! {encode} )"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--address", default="127.0.0.1")
    parser.add_argument("--file")
    parser.add_argument("--codec", choices=["h264", "h265"], default="h264")
    parser.add_argument("--size", default="768x576")
    parser.add_argument("--fps", type=int, default=10)
    parser.add_argument("--user")
    parser.add_argument("--password")
    args = parser.parse_args()

    Gst.init(None)
    server = GstRtspServer.RTSPServer()
    server.set_address(args.address)
    server.set_service(str(args.port))
    factory = GstRtspServer.RTSPMediaFactory()
    factory.set_launch(pipeline(args))
    if args.user:
        auth = GstRtspServer.RTSPAuth()
        token = GstRtspServer.RTSPToken()
        token.set_string(GstRtspServer.RTSP_TOKEN_MEDIA_FACTORY_ROLE, "camera-user")
        auth.add_basic(GstRtspServer.RTSPAuth.make_basic(args.user, args.password), token)
        server.set_auth(auth)
        permissions = GstRtspServer.RTSPPermissions()
        permissions.add_permission_for_role("camera-user", "media.factory.access", True)
        permissions.add_permission_for_role("camera-user", "media.factory.construct", True)
        factory.set_permissions(permissions)
    server.get_mount_points().add_factory("/cam", factory)
    if server.attach(None) == 0:
        sys.exit(f"camera.py: cannot listen on {args.address}:{args.port}")
    print(f"ready rtsp://{args.address}:{args.port}/cam", flush=True)
    loop = GLib.MainLoop()
    GLib.unix_signal_add(GLib.PRIORITY_DEFAULT, signal.SIGTERM, loop.quit)
    GLib.unix_signal_add(GLib.PRIORITY_DEFAULT, signal.SIGINT, loop.quit)
    loop.run()


if __name__ == "__main__":
    main()
