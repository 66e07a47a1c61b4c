"""What the independent Cyclone DDS peers (costmap_listener.py, plan_client.py) share.

Eclipse Cyclone DDS from Python (`cyclonedds` on PyPI) and nothing of isochron or
ROS: the DDS configuration that keeps a peer on the loopback interface, the QoS
ROS 2 middlewares speak, the ROS 2 name mangling of topics, and one JSON line per
message on standard output. The scripts import it from their own folder.

Call `configure()` before anything creates a Cyclone DDS domain.
"""

import json
import os
import sys

LOOPBACK_ONLY = """<CycloneDDS><Domain id="any">
  <General>
    <Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>
    <AllowMulticast>false</AllowMulticast>
  </General>
  <Discovery>
    <ParticipantIndex>auto</ParticipantIndex>
    <MaxAutoParticipantIndex>30</MaxAutoParticipantIndex>
    <Peers><Peer address="127.0.0.1"/></Peers>
  </Discovery>
</Domain></CycloneDDS>"""


def configure(multicast=False):
    """Loopback-only unicast discovery, or with `multicast` Cyclone's default
    (multicast SPDP on every interface). Must run before the domain exists."""
    if multicast:
        os.environ.pop("CYCLONEDDS_URI", None)
    else:
        os.environ["CYCLONEDDS_URI"] = LOOPBACK_ONLY


def reliable_qos(latched, depth):
    """Reliable QoS, transient-local when `latched` (else volatile), keeping the
    last `depth` samples, accepting the plain CDR (XCDR1) ROS 2 middlewares send."""
    from cyclonedds.core import Policy, Qos
    from cyclonedds.util import duration

    return Qos(
        Policy.Reliability.Reliable(duration(seconds=1)),
        Policy.Durability.TransientLocal if latched else Policy.Durability.Volatile,
        Policy.History.KeepLast(depth),
        Policy.DataRepresentation(use_cdrv0_representation=True, use_xcdrv2_representation=True),
    )


def absolute(name):
    """A ROS 2 name with its leading slash."""
    return name if name.startswith("/") else "/" + name


def emit(obj):
    """One JSON line on standard output, flushed at once (the test reads it live)."""
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def ros_type(name, **fields):
    """The Cyclone DDS type of the ROS 2 message `name` ("pkg/msg/Type" or
    "pkg/srv/Type_Request"), with its DDS name ("pkg::msg::dds_::Type_") and
    `fields` in their declaration order (name=IDL type)."""
    import types
    from dataclasses import dataclass

    from cyclonedds.idl import IdlStruct

    package, kind, short = name.split("/")
    typename = f"{package}::{kind}::dds_::{short}_"
    cls = types.new_class(
        short,
        (IdlStruct,),
        {"typename": typename},
        lambda namespace: namespace["__annotations__"].update(fields),
    )
    return dataclass(cls)
