"""NatNet (OptiTrack Motive) motion-capture client, wire-format parsers and fake servers for tests."""

from drivers.natnet.client import NatNetSource, NatNetStats
from drivers.natnet.fake import (
                                 FakeBody,
                                 FakeFrame,
                                 FakeNatNetServer,
                                 encode_frame,
                                 encode_model_definitions,
                                 encode_server_info,
)
from drivers.natnet.fake_motive import FakeMotive
from drivers.natnet.messages import MessageId, ServerInfo, build_connect, build_request, parse_server_info, split_packet
from drivers.natnet.modeldef import DescriptorType, ModelDefinitions, RigidBodyDescription, parse_model_definitions
from drivers.natnet.packets import MocapFrame, parse_frame

__all__ = [
    "DescriptorType",
    "FakeBody",
    "FakeFrame",
    "FakeMotive",
    "FakeNatNetServer",
    "MessageId",
    "MocapFrame",
    "ModelDefinitions",
    "NatNetSource",
    "NatNetStats",
    "RigidBodyDescription",
    "ServerInfo",
    "build_connect",
    "build_request",
    "encode_frame",
    "encode_model_definitions",
    "encode_server_info",
    "parse_frame",
    "parse_model_definitions",
    "parse_server_info",
    "split_packet",
]
