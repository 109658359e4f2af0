"""NatNet (OptiTrack Motive) motion-capture client, wire-format parser and a fake server for tests."""

from drivers.natnet.client import NatNetSource, NatNetStats
from drivers.natnet.fake import FakeBody, FakeFrame, FakeNatNetServer, encode_frame, encode_server_info
from drivers.natnet.packets import (MessageId, MocapFrame, ServerInfo, build_connect, parse_frame,
                                    parse_server_info, split_packet)

__all__ = [
    "FakeBody",
    "FakeFrame",
    "FakeNatNetServer",
    "MessageId",
    "MocapFrame",
    "NatNetSource",
    "NatNetStats",
    "ServerInfo",
    "build_connect",
    "encode_frame",
    "encode_server_info",
    "parse_frame",
    "parse_server_info",
    "split_packet",
]
