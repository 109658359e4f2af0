"""The cellcal Zenoh bus: mocap frames and robot joint states as small binary samples.

Only :mod:`drivers.bus.session`, :mod:`drivers.bus.mocap` and :mod:`drivers.bus.joints` import zenoh,
and only inside the functions that need it, so importing this package stays cheap.
"""

from drivers.bus.inbox import InboxStats
from drivers.bus.joints import JointStatePublisher, JointStateSubscriber
from drivers.bus.mocap import MocapBridge, MocapSample, ZenohMocapSource
from drivers.bus.payloads import decode_joints, decode_mocap, encode_joints, encode_mocap
from drivers.bus.session import joints_key, mocap_key, open_session, session_settings, wait_for_subscriber

__all__ = [
    "InboxStats",
    "JointStatePublisher",
    "JointStateSubscriber",
    "MocapBridge",
    "MocapSample",
    "ZenohMocapSource",
    "decode_joints",
    "decode_mocap",
    "encode_joints",
    "encode_mocap",
    "joints_key",
    "mocap_key",
    "open_session",
    "session_settings",
    "wait_for_subscriber",
]
