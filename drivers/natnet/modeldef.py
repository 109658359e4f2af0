"""NatNet model definitions (``NAT_MODELDEF``, the reply to ``NAT_REQUEST_MODELDEF``): a pure parser.

The payload is ``int32 count`` data descriptions, each ``int32 type`` then (NatNet 4.1 and later) an
``int32`` byte count of the description, then the description itself. Layouts follow the
``__unpack_*_description`` functions of the SDK's ``NatNetClient.py``:

- 0 marker set: name, ``int32 n``, n marker names.
- 1 rigid body: name, ``int32 id``, ``int32 parent id``, offset (3 floats, m), (4.2+) a 16-byte rotation,
  (3.0+) ``int32 n``, n marker offsets (3 floats each, m), n ``int32`` active labels, (4.0+) n names.
- 2 skeleton: name, ``int32 id``, ``int32 n``, n rigid-body descriptions (the bones).
- 3 force plate, 4 device, 5 camera, 6 asset (4.1+): parsed only to be skipped.

Rigid bodies and marker sets are kept; everything else is walked field by field to find the next
description, and from 4.1 on every description must fill exactly its byte count (an unknown type is skipped
by that count). Names are NUL-terminated UTF-8. Lengths are converted from metres to millimetres.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from drivers.errors import ProtocolError
from drivers.natnet.messages import check_version, has_byte_counts
from drivers.natnet.reader import DEVICE, Reader

M_TO_MM = 1000.0
_VEC3 = struct.Struct("<3f")


class DescriptorType(enum.IntEnum):
    """Data-description types of ``NAT_MODELDEF``."""

    MARKER_SET = 0
    RIGID_BODY = 1
    SKELETON = 2
    FORCE_PLATE = 3
    DEVICE = 4
    CAMERA = 5
    ASSET = 6


@dataclass(frozen=True)
class RigidBodyDescription:
    """One rigid body as Motive defines it.

    Attributes:
        name: the rigid-body name in Motive (what ``cell.yaml`` refers to).
        body_id: the id frames carry for this body.
        parent_id: id of the parent body, -1 when none.
        offset_mm: pivot offset relative to the parent [mm], shape (3,).
        marker_offsets_mm: marker positions in the body frame [mm], shape (N, 3) (NatNet 3.0+).
        marker_ids: active label of each marker (0 for passive markers), N ints.
        marker_names: marker names (NatNet 4.0+; empty strings before).
    """

    name: str
    body_id: int
    parent_id: int
    offset_mm: np.ndarray
    marker_offsets_mm: np.ndarray
    marker_ids: tuple[int, ...]
    marker_names: tuple[str, ...]


@dataclass(frozen=True)
class ModelDefinitions:
    """The parsed ``NAT_MODELDEF``.

    Attributes:
        rigid_bodies: rigid-body descriptions, in the server's order (skeleton bones excluded).
        marker_sets: (name, marker names) per marker set.
        skeletons: names of the skeletons.
        type_counts: how many descriptions of each type the packet held, skipped ones included.
    """

    rigid_bodies: tuple[RigidBodyDescription, ...]
    marker_sets: tuple[tuple[str, tuple[str, ...]], ...]
    skeletons: tuple[str, ...]
    type_counts: dict[int, int]

    def rigid_body_ids(self) -> dict[str, int]:
        """Rigid-body name -> id."""
        return {b.name: b.body_id for b in self.rigid_bodies}

    def missing_rigid_bodies(self, names: Iterable[str]) -> list[str]:
        """The ``names`` no rigid body is defined with, in the order given."""
        defined = self.rigid_body_ids()
        return [n for n in names if n not in defined]


def _rigid_body(r: Reader, version: tuple[int, int]) -> RigidBodyDescription:
    name = r.cstring("rigid body name")
    body_id, parent_id = r.i32("rigid body id"), r.i32("rigid body parent id")
    offset = np.array(r.unpack(_VEC3, "rigid body offset")) * M_TO_MM
    if version >= (4, 2):
        r.take(16, "rigid body rotation")
    n = r.count("rigid body marker count", 16)
    offsets = np.frombuffer(r.take(12 * n, "rigid body marker offsets"), dtype="<f4").reshape(n, 3)
    ids = tuple(int(i) for i in np.frombuffer(r.take(4 * n, "rigid body marker labels"), dtype="<i4"))
    names = tuple(r.cstring("rigid body marker name") for _ in range(n)) if version >= (4, 0) else ("",) * n
    return RigidBodyDescription(name, body_id, parent_id, offset, offsets.astype(float) * M_TO_MM, ids, names)


def _marker_set(r: Reader) -> tuple[str, tuple[str, ...]]:
    name = r.cstring("marker set name")
    return name, tuple(r.cstring("marker name") for _ in range(r.count("marker set marker count", 1)))


def _skeleton(r: Reader, version: tuple[int, int]) -> str:
    name = r.cstring("skeleton name")
    r.i32("skeleton id")
    for _ in range(r.count("skeleton bone count", 21)):
        _rigid_body(r, version)
    return name


def _strings(r: Reader, what: str) -> None:
    for _ in range(r.count(f"{what} count", 1)):
        r.cstring(what)


def _skip_force_plate(r: Reader) -> None:
    r.i32("force plate id")
    r.cstring("force plate serial number")
    r.take(4 + 4 + 12 + 12 * 12 * 4 + 12 * 4 + 4 + 4, "force plate geometry")  # size, origin, cal, corners, types
    _strings(r, "force plate channel name")


def _skip_device(r: Reader) -> None:
    r.i32("device id")
    r.cstring("device name")
    r.cstring("device serial number")
    r.take(8, "device type and channel data type")
    _strings(r, "device channel name")


def _skip_camera(r: Reader) -> None:
    r.cstring("camera name")
    r.take(12 + 16, "camera position and orientation")


def _skip_asset(r: Reader, version: tuple[int, int]) -> None:
    r.cstring("asset name")
    r.take(8, "asset type and id")
    for _ in range(r.count("asset rigid body count", 21)):
        _rigid_body(r, version)
    for _ in range(r.count("asset marker count", 23)):
        r.cstring("asset marker name")
        r.take(4 + 12 + 4 + 2, "asset marker")  # id, initial position, size, params


def parse_model_definitions(payload: bytes | memoryview, version: tuple[int, int]) -> ModelDefinitions:
    """Parse the payload (after the 4-byte header) of a ``NAT_MODELDEF`` packet.

    Args:
        payload: packet bytes after the header.
        version: NatNet stream (major, minor), at least (3, 0).

    Raises:
        ProtocolError: truncated, a 4.1+ byte count that does not match, or (before 4.1) an unknown type.
    """
    version = check_version(version)
    r = Reader(payload)
    bodies, marker_sets, skeletons = [], [], []
    counts: dict[int, int] = {}
    for _ in range(r.count("data description count", 4)):
        kind = r.i32("data description type")
        size = r.count("data description byte count", 1) if has_byte_counts(version) else None
        start = r.offset
        counts[kind] = counts.get(kind, 0) + 1
        if kind == DescriptorType.RIGID_BODY:
            bodies.append(_rigid_body(r, version))
        elif kind == DescriptorType.MARKER_SET:
            marker_sets.append(_marker_set(r))
        elif kind == DescriptorType.SKELETON:
            skeletons.append(_skeleton(r, version))
        elif kind == DescriptorType.FORCE_PLATE:
            _skip_force_plate(r)
        elif kind == DescriptorType.DEVICE:
            _skip_device(r)
        elif kind == DescriptorType.CAMERA:
            _skip_camera(r)
        elif kind == DescriptorType.ASSET and version >= (4, 1):
            _skip_asset(r, version)
        elif size is not None:
            r.take(size, f"data description of unknown type {kind}")
        else:
            raise ProtocolError(DEVICE, f"unknown data description type {kind} in NatNet {version[0]}.{version[1]} "
                                        f"(known: {', '.join(f'{t.value} {t.name}' for t in DescriptorType)})")
        if size is not None:
            r.expect_consumed(start, size, f"data description type {kind}")
    return ModelDefinitions(tuple(bodies), tuple(marker_sets), tuple(skeletons), counts)
