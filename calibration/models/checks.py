"""Checks a model file passes before any prediction is made from it.

:func:`check_model_data` runs on the decoded file, whatever the model kind: every number finite, every
``R_*`` matrix a rotation, the robot recorded, the method known. :func:`check_model_for` runs on a loaded
model once the caller knows which arm it is for: the recorded robot must be that arm, and the model's
reference geometry (joint axes and link vectors) must lie near that arm's nominal geometry from the robot
YAML, so a model of another robot type is refused even when its robot name was edited. Each failure is a
:class:`~calibration.errors.ModelFileError` naming the file and the key.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from calibration.errors import ModelFileError
from calibration.kinematics.poe import poe_from_dict
from calibration.method_names import METHODS

if TYPE_CHECKING:
    from calibration.kinematics.poe import PoeModel
    from calibration.models.base import KinematicModel

#: Largest entry of ``R^T R - I`` accepted for a stored rotation (hand-edited files keep ~7 digits).
ROTATION_TOLERANCE = 1e-6
#: A fitted link vector (between joint 1 and the flange) lies this close to the nominal one [mm]; fits move
#: them by a few mm, while the cell's two robot types differ by 146 mm or more.
LINK_TOLERANCE_MM = 50.0
#: A fitted joint axis lies this close to the nominal one [deg].
AXIS_TOLERANCE_DEG = 5.0
#: Methods a model file may record besides the fitting methods: diagnose results and simulation twins.
OTHER_METHODS = ("diagnose", "twin")
#: Largest magnitude of any number in a model file. The largest a fit writes is a lumped gravity torque of ~2e4
#: N mm (every kind of tests/calibration/models/test_model_kinds.py); 1e308, which YAML reads as text and numpy as a float,
#: is refused.
MAX_NUMBER = 1e9
#: Largest magnitude of a position in a model file [mm]: link vectors ``P`` (base and flange included), ``p_*``
#: offsets and ``T_*`` transforms. The arms reach ~2 m; the largest link vector written is 1082 mm.
MAX_POSITION_MM = 1e4
#: Largest list in a model file (the biggest a fit writes: an interpolator's training values, one row per
#: calibration pose, a few thousand); a longer one is refused naming its key before any shape is built.
MAX_LIST_LENGTH = 1_000_000
#: Largest model file read [bytes]. A model file is a few hundred kB at most (a neural interpolator's weights).
MAX_MODEL_FILE_BYTES = 64 * 1024 * 1024


def known_methods() -> tuple[str, ...]:
    """Every method a model file may record."""

    return tuple(METHODS) + OTHER_METHODS


_CONTAINERS = (dict, list, tuple)


def _leaves(node: Any, key: str) -> Iterator[tuple[str, Any]]:
    """Every non-container value under ``node`` with its dotted key, depth first in file order.

    A scalar child is yielded in place rather than through a generator of its own (a neural model's weights are
    tens of thousands of leaves: one generator each made a check 0.1 s); the order and the keys are unchanged."""
    if isinstance(node, dict):
        for k, v in node.items():
            sub = f"{key}.{k}" if key else str(k)
            if isinstance(v, _CONTAINERS):
                yield from _leaves(v, sub)
            else:
                yield sub, v
    elif isinstance(node, (list, tuple)):
        for i, v in enumerate(node):
            if isinstance(v, _CONTAINERS):
                yield from _leaves(v, f"{key}[{i}]")
            else:
                yield f"{key}[{i}]", v
    else:
        yield key, node


def _mappings(node: Any, key: str) -> Iterator[tuple[str, dict[str, Any]]]:
    """Every mapping under ``node`` (itself included) with its dotted key, depth first; scalars are not entered."""
    if isinstance(node, dict):
        yield key, node
        for k, v in node.items():
            if isinstance(v, _CONTAINERS):
                yield from _mappings(v, f"{key}.{k}" if key else str(k))
    elif isinstance(node, (list, tuple)):
        for i, v in enumerate(node):
            if isinstance(v, _CONTAINERS):
                yield from _mappings(v, f"{key}[{i}]")


def check_model_structure(data: Any, path: str | Path = "") -> None:
    """Refuse a decoded model file whose structure cannot be walked safely: a container reached twice (a YAML
    alias ``*name`` of an anchor ``&name``: a "billion laughs" file expands to 10^9 leaves through them) or a list
    longer than :data:`MAX_LIST_LENGTH`. Runs before anything else walks the file, in time proportional to its size.

    Raises:
        ModelFileError: naming the key of the shared or too long container.
    """
    seen: set[int] = set()
    stack: list[tuple[str, Any]] = [("", data)]
    while stack:
        key, node = stack.pop()
        if id(node) in seen:
            raise ModelFileError(path, key or "(top level)", "refers back to a block used elsewhere (a YAML alias "
                                                             "*name of an anchor &name): a model file holds no aliases")
        seen.add(id(node))
        if isinstance(node, dict):
            items: Any = ((f"{key}.{k}" if key else str(k), v) for k, v in node.items())
        else:
            if len(node) > MAX_LIST_LENGTH:
                raise ModelFileError(path, key, f"a list of {len(node)} entries; a model file holds at most "
                                                f"{MAX_LIST_LENGTH} per list")
            items = ((f"{key}[{i}]", v) for i, v in enumerate(node))
        stack.extend(reversed([(k, v) for k, v in items if isinstance(v, _CONTAINERS)]))  # file order


def _is_position(key: str) -> bool:
    """Whether a dotted key holds a position [mm]: ``P`` (link vectors), ``p_*`` and ``T_*`` blocks."""
    for part in key.split("."):
        name = part.split("[", 1)[0]
        if name == "P" or name.startswith(("p_", "T_")):
            return True
    return False


def _number_problem(value: Any, key: str) -> str | None:
    """Why a leaf cannot be a number of a model file, or None. Text that reads as a number counts as one (YAML
    reads a plain ``nan``, ``inf`` or ``1e308`` as text, and numpy converts that text to a float)."""
    if type(value) is float and -MAX_POSITION_MM <= value <= MAX_POSITION_MM:  # nearly every leaf: done at once
        return None
    if isinstance(value, bool):
        return None
    if isinstance(value, str):
        try:
            number = float(value)
        except ValueError:
            return None
        shown = f"{value!r} (text read as {number:g})"
    elif isinstance(value, (int, float)):
        try:
            number = float(value)
        except OverflowError:
            return f"expected a number within +-{MAX_NUMBER:g}, got an integer of {len(str(abs(value)))} digits"
        shown = f"{value}"
    else:
        return None
    if not math.isfinite(number):
        return f"expected a finite number, got {shown}"
    if abs(number) <= MAX_POSITION_MM:
        return None
    bound, unit = (MAX_POSITION_MM, " mm, a position") if _is_position(key) else (MAX_NUMBER, "")
    if abs(number) > bound:
        return f"expected a number within +-{bound:g}{unit}, got {shown}"
    return None


def check_model_numbers(data: Any, path: str | Path = "") -> None:
    """Refuse any number of a decoded model file (or of a model's ``to_dict``) that is not finite or beyond its
    physical bound (:data:`MAX_POSITION_MM` for positions, :data:`MAX_NUMBER` otherwise), text included.

    Raises:
        ModelFileError: naming the key.
    """
    for key, value in _leaves(data, ""):
        problem = _number_problem(value, key)
        if problem is not None:
            raise ModelFileError(path, key, problem)


def _check_rotation(path: str | Path, key: str, value: Any) -> None:
    try:
        R = np.array(value, dtype=float)
    except (TypeError, ValueError):
        R = None
    if R is None or R.shape != (3, 3):
        raise ModelFileError(path, key, "expected a 3x3 rotation matrix")
    if not np.all(np.isfinite(R)):
        raise ModelFileError(path, key, "expected a 3x3 rotation matrix of finite numbers")
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if not err <= ROTATION_TOLERANCE:
        raise ModelFileError(path, key, f"not a rotation: its columns are not orthonormal (R^T R - I up to "
                                        f"{err:.2g}, tolerance {ROTATION_TOLERANCE:g})")
    if not np.linalg.det(R) > 0:
        raise ModelFileError(path, key, "not a rotation: determinant -1 (a reflection)")


def check_model_data(data: dict[str, Any], path: str | Path = "") -> None:
    """Refuse a decoded model file whose numbers, rotations, robot or method cannot be used.

    Raises:
        ModelFileError: an alias or a too long list (:func:`check_model_structure`), a number (or text read as
            one) NaN, infinite or beyond its bound (:func:`check_model_numbers`), an ``R_*`` entry that is not a
            rotation (orthonormal, determinant +1), the robot missing, or the method unknown (the message lists
            the valid ones).
    """
    check_model_structure(data, path)
    check_model_numbers(data, path)
    for key, mapping in _mappings(data, ""):
        for k, v in mapping.items():
            if isinstance(k, str) and k.startswith("R_"):
                _check_rotation(path, f"{key}.{k}" if key else k, v)
    robot = data.get("robot")
    if not isinstance(robot, str) or not robot:
        raise ModelFileError(path, "robot", f"expected the name of the robot the model was fitted for (R1, R2), "
                                            f"got {robot!r}; every {data.get('schema')} file records it")
    method = data.get("method")
    if method not in known_methods():
        raise ModelFileError(path, "method", f"unknown method {method!r}; valid: {', '.join(known_methods())}")


def reference_geometry(model: KinematicModel) -> PoeModel:
    """The geometry a model is built on (its POE geometry, or the nominal of an extended or CDC model; of the
    wrapped model for ``diagnosed`` and ``rebased``)."""

    d = model.to_dict()
    while True:
        for key in ("geometry", "nominal"):
            if isinstance(d.get(key), dict):
                return poe_from_dict(d[key])
        inner = next((d[key] for key in ("base", "inner") if isinstance(d.get(key), dict)), None)
        if inner is None:
            raise ModelFileError("", "", f"a {model.kind} model has no geometry to check")
        d = inner


def check_model_for(model: KinematicModel, robot: str, nominal: PoeModel | None = None,
                    path: str | Path = "") -> None:
    """Refuse a model that is not for ``robot``.

    Args:
        model: a loaded model.
        robot: the arm the caller will use it for (``--robot``, or the arm a plan assigns it to).
        nominal: that arm's nominal geometry (robot YAML); when given, the model's joint axes must lie within
            :data:`AXIS_TOLERANCE_DEG` and its link vectors (joint 1 to the flange; base and tool excluded,
            which registration and tool fits move freely) within :data:`LINK_TOLERANCE_MM` of it.
        path: the model file, for the message.

    Raises:
        ModelFileError: the model records another robot, or its geometry is another robot type's.
    """
    if model.robot != robot:
        raise ModelFileError(path, "robot", f"the model is for {model.robot}, not {robot} (the file records robot "
                                            f"{model.robot!r}; give {robot}'s model)")
    if nominal is None:
        return
    geo = reference_geometry(model)
    if geo.H.shape != nominal.H.shape:
        raise ModelFileError(path, "geometry", f"{geo.n_joints} joints, but {robot} has {nominal.n_joints}")
    cos = np.clip(np.sum(geo.H * nominal.H, axis=0), -1.0, 1.0)
    angle = np.degrees(np.arccos(cos))
    links = np.linalg.norm(geo.P[:, 1:-1] - nominal.P[:, 1:-1], axis=0)
    if links.max() > LINK_TOLERANCE_MM:
        j = int(np.argmax(links))
        what = (f"link vector P[{j + 1}] differs from the robot YAML's by {links[j]:.0f} mm "
                f"(tolerance {LINK_TOLERANCE_MM:g} mm)")
    elif angle.max() > AXIS_TOLERANCE_DEG:
        j = int(np.argmax(angle))
        what = (f"joint {j + 1}'s axis differs from the robot YAML's by {angle[j]:.1f} deg "
                f"(tolerance {AXIS_TOLERANCE_DEG:g} deg)")
    else:
        return
    raise ModelFileError(path, "geometry", f"not {robot}'s geometry: {what}; a model of another robot type?")
