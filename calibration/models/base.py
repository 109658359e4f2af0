"""The model base, its registry and the model files.

Every model maps joint angles to the tool-marker pose, ``fk(q) -> (R (N, 3, 3), p (N, 3))``, and saves to
one versioned, human-readable file (``.yaml``/``.yml`` or ``.json``) that loads back to bit-identical
predictions (floats are written with their shortest exact repr). A file is checked when it is loaded (and a
model before it is saved) by :mod:`calibration.model_checks`: finite numbers, rotations, the recorded robot,
a known method, and each kind's own blocks; :func:`load_model` also checks it against the arm it is used for.

A model kind declares its parameter blocks once (:meth:`KinematicModel.blocks`, a tuple of :class:`Block`)
and from that declaration gives its pose, its parameter and joint Jacobians and its casadi expression
(:meth:`KinematicModel.casadi`). The kinds live next to this module: ``constant``, ``pi``, ``cdc``,
``physics``, ``diagnosed``, ``rebased``; each registers itself when its module is imported (:data:`MODEL_KIND_MODULES`
says where, so loading a file imports the one it needs).
"""

from __future__ import annotations

import abc
import importlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import yaml

from calibration.errors import DataError, ModelError, ModelFileError, parse_error_text
from calibration.files import atomic_write_text, read_input_text
from calibration.model_checks import (
    MAX_MODEL_FILE_BYTES,
    MAX_POSITION_MM,
    check_model_data,
    check_model_for,
    check_model_numbers,
    check_model_structure,
)
from calibration.poe import PoeModel
from calibration.yamlio import safe_load

#: The schema files are written with. /2 since the extrapolation guard's per-effect rule (the training region's
#: ``rule``): a cellcal that reads /1 only would load a /2 file's region, ignore its rule and predict up to 13 mm
#: differently with no warning, so it must refuse the file instead. /1 files are read as before.
SCHEMA = "cellcal.model/2"
#: The schemas this version reads.
READABLE_SCHEMAS = ("cellcal.model/1", SCHEMA)
#: Where each model kind is defined; imported on first load so this module imports none of them.
MODEL_KIND_MODULES = {"constant": "calibration.models.constant", "cdc": "calibration.models.cdc",
                      "pi": "calibration.models.pi", "physics": "calibration.models.physics",
                      "diagnosed": "calibration.models.diagnosed", "rebased": "calibration.models.rebased"}
log = logging.getLogger("cellcal.calibration")


@dataclass(frozen=True)
class Block:
    """One named block of a model's parameter vector (a model kind declares its blocks once)."""

    name: str
    names: tuple[str, ...]

    @property
    def size(self) -> int:
        return len(self.names)


def poe_to_dict(m: PoeModel) -> dict[str, Any]:
    return {"H": m.H.T.tolist(), "P": m.P.T.tolist(), "R_flange": m.R_flange.tolist(),
            "R_flange_tool": m.R_flange_tool.tolist(), "p_flange_tool": m.p_flange_tool.tolist()}


def poe_from_dict(d: dict[str, Any]) -> PoeModel:
    return PoeModel(np.array(d["H"], dtype=float).T, np.array(d["P"], dtype=float).T,
                    np.array(d["R_flange"], dtype=float), np.array(d["R_flange_tool"], dtype=float),
                    np.array(d["p_flange_tool"], dtype=float))


class KinematicModel(abc.ABC):
    """A fitted model of one robot: joint angles in, tool-marker pose out."""

    kind: ClassVar[str]
    _registry: ClassVar[dict[str, type[KinematicModel]]] = {}
    robot: str
    method: str
    info: dict[str, Any]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "kind" in cls.__dict__:
            KinematicModel._registry[cls.kind] = cls

    @abc.abstractmethod
    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose for joint angles q [rad], shape (N, 6): ``(R (N, 3, 3), p (N, 3) [mm])``."""

    def fk_context(self, q: np.ndarray, context: Any) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose for joint angles q [rad] (N, 6) and a per-sample context (time, approach directions, payload:
        :mod:`calibration.physics.base`); a model with no context-dependent effect ignores the context."""
        return self.fk(q)

    @property
    def context_keys(self) -> frozenset[str]:
        """The context entries :meth:`fk_context` reads (:attr:`calibration.physics.base.Effect.context_keys`):
        none for a model without context-dependent effects."""
        return frozenset()

    def with_region(self, region: Any) -> KinematicModel:
        """The same model with another training region (a :class:`calibration.models.guard.Region`, or None: none,
        which turns the extrapolation guard off)."""
        from dataclasses import replace

        from calibration.models.guard import REGION_KEY

        info = {k: v for k, v in self.info.items() if k != REGION_KEY}
        return replace(self, info=info if region is None else {**info, REGION_KEY: region.to_dict()})  # type: ignore[type-var]

    def out_of_range(self, q: np.ndarray) -> np.ndarray:
        """Boolean mask (N,) of configurations outside the region the model was fitted on."""
        return np.zeros(np.atleast_2d(q).shape[0], dtype=bool)

    def interpolation(self) -> Any:
        """The interpolator of the configuration-dependent parameters (a
        :class:`calibration.interpolation.Interpolator`), or None for a model whose parameters are constant.
        A kind that wraps another model answers with the wrapped one's: an analysis asks any model, never its
        type."""
        return None

    def region(self) -> Any:
        """The per-joint range of the training data (a :class:`calibration.models.guard.Region`), or None when
        the model was saved without it."""
        from calibration.models.guard import region_of

        return region_of(self.info)

    def pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose for joint angles q [rad] (N, 6): ``(R (N, 3, 3), p (N, 3) [mm])`` (same as :meth:`fk`)."""
        return self.fk(q)

    def blocks(self) -> tuple[Block, ...]:
        """The parameter blocks of :meth:`vector`, in layout order."""
        return ()

    def vector(self) -> np.ndarray:
        """The parameters the Jacobians are taken with respect to, shape (m,) (layout of :meth:`blocks`)."""
        return np.zeros(0)

    def with_vector(self, theta: np.ndarray) -> KinematicModel:
        """The same model with other parameters (m,)."""
        raise ModelError(f"a {self.kind} model has no parameter vector")

    def casadi(self, q: Any, theta: Any = None, q_at: Any = None) -> Any:
        """The pose as casadi expressions (a :class:`calibration.casadi_expr.CasadiPose`).

        Args:
            q: casadi symbols (or expressions) of the joint angles the kinematics see [rad] (6,).
            theta: casadi symbols for :meth:`vector` (m,), or None for the model's own values (constants).
            q_at: the joint reading configuration-dependent parameters are evaluated at (default ``q``); it
                differs from ``q`` when joint effects deflect the joints before the kinematics.
        """
        raise ModelError(f"a {self.kind} model has no casadi expression")

    def pose_at(self, q: np.ndarray, q_at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pose at the joint angles q (N, 6) the kinematics see, configuration-dependent parameters at the
        reading ``q_at`` (N, 6) (they differ when joint effects act on this model, see ``diagnosed``)."""
        raise ModelError(f"a {self.kind} model cannot carry effects; valid bases: pi, cdc")

    def effects_arm(self) -> PoeModel:
        """The POE arm the effects acting on this model see (their gravity torques, their link growth)."""
        raise ModelError(f"a {self.kind} model cannot carry effects; valid bases: pi, cdc")

    def effects_geometry(self, theta: Any = None) -> tuple[PoeModel, Any, Any]:
        """:meth:`effects_arm` in casadi: ``(arm with tool, H (3, n), P (3, n+1))``, the geometry from
        ``theta`` (symbols for :meth:`vector`) or from the model's own values when None."""
        raise ModelError(f"a {self.kind} model cannot carry effects; valid bases: pi, cdc")

    def urdf_geometry(self) -> Any:
        """The constant geometry a URDF can hold and what it loses (a :class:`calibration.urdf.UrdfGeometry`).

        Raises:
            ModelError: this kind has no constant geometry to export.
        """
        raise ModelError(f"a {self.kind} model cannot be exported as a URDF; exportable kinds: "
                         "constant, pi, cdc, physics, diagnosed, rebased")

    def jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pose and ``d[p (mm); rotation (rad)] / d vector`` (N, 6, m) in the base frame.

        By default exact, from the model's own casadi expression; kinds with an analytic form override it.
        """
        from calibration.casadi_expr import pose_jacobians

        R, p = self.fk(q)
        return R, p, pose_jacobians(lambda qs, ts: self.casadi(qs, ts), q, self.vector())[0]

    def jacobian_q(self, q: np.ndarray) -> np.ndarray:
        """``d[p (mm); rotation (rad)] / dq`` (N, 6, 6): exact, from the model's own casadi expression."""
        from calibration.casadi_expr import pose_jacobians

        return pose_jacobians(lambda qs, ts: self.casadi(qs, ts), q, self.vector(), wrt_theta=False)[1]

    @property
    @abc.abstractmethod
    def n_parameters(self) -> int:
        """Number of identified parameters (for reports)."""

    @abc.abstractmethod
    def _body(self) -> dict[str, Any]:
        """Kind-specific content of the model file."""

    @classmethod
    @abc.abstractmethod
    def _from_body(cls, robot: str, method: str, info: dict[str, Any], body: dict[str, Any]) -> KinematicModel:
        """Inverse of :meth:`_body`."""

    def to_dict(self) -> dict[str, Any]:
        return {"schema": SCHEMA, "kind": self.kind, "robot": self.robot, "method": self.method,
                "n_parameters": self.n_parameters, "info": self.info, **self._body()}

    @staticmethod
    def from_dict(d: dict[str, Any]) -> KinematicModel:
        if d.get("schema") not in READABLE_SCHEMAS:
            raise ModelError(f"unsupported model schema {d.get('schema')!r}; expected one of {READABLE_SCHEMAS}")
        kind = d.get("kind")
        return model_class(kind)._from_body(d["robot"], d["method"], d.get("info", {}), d)


def model_class(kind: Any) -> type[KinematicModel]:
    """The class of a model kind, imported on first use.

    Raises:
        ModelError: the kind is unknown (the message lists the valid ones).
    """
    if kind in MODEL_KIND_MODULES and kind not in KinematicModel._registry:
        importlib.import_module(MODEL_KIND_MODULES[kind])  # defining the class registers the kind
    if kind not in KinematicModel._registry:
        raise ModelError(f"unknown model kind {kind!r}; valid: {', '.join(sorted(MODEL_KIND_MODULES))}")
    return KinematicModel._registry[kind]


def _plain(obj: Any) -> Any:
    """Convert numpy scalars/arrays inside ``obj`` to plain Python for YAML/JSON."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def save_model(model: KinematicModel, path: str | Path) -> None:
    """Write a model file (JSON for ``.json``, YAML otherwise), atomically.

    Raises:
        ModelFileError: the model would be refused when loaded (a value not finite, ...); nothing is written.
        OutputError: the path is refused or the write failed (see :func:`calibration.files.atomic_open`).
    """
    path = Path(path)
    data = _plain(model.to_dict())
    check_model_data(data, path)
    if path.suffix.lower() == ".json":
        text = json.dumps(data, indent=1)
    else:
        text = yaml.dump(data, Dumper=getattr(yaml, "CSafeDumper", yaml.SafeDumper), sort_keys=False,
                         default_flow_style=None, width=120)
    atomic_write_text(path, text)


def _read_model_file(path: Path) -> dict[str, Any]:
    """The decoded model file: a regular file of at most :data:`~calibration.model_checks.MAX_MODEL_FILE_BYTES`
    (a FIFO or a device would block or never end), whose structure can be walked (no aliases, no list beyond
    :data:`~calibration.model_checks.MAX_LIST_LENGTH`)."""
    try:
        text = read_input_text(path, MAX_MODEL_FILE_BYTES)  # a regular file: a FIFO or /dev/zero is refused
    except FileNotFoundError:
        raise DataError(path, None, None, "model file not found") from None
    except IsADirectoryError:
        raise DataError(path, None, None, "is a folder, not a model file") from None
    except UnicodeDecodeError:
        raise DataError(path, None, None, "not a model file (binary content; expected YAML or JSON text)") from None
    except OSError as e:
        raise DataError(path, None, None, f"cannot read the model file ({e.strerror or e})") from e
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            data = safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError, RecursionError) as e:
        raise DataError(path, None, None, f"not a valid model file ({parse_error_text(e)})") from e
    if not isinstance(data, dict):
        raise DataError(path, None, None, "not a model file (expected a mapping)")
    check_model_structure(data, path)
    return data


def load_model(path: str | Path, robot: str | None = None, nominal: PoeModel | None = None) -> KinematicModel:
    """Read and check a model file written by :func:`save_model`.

    Args:
        path: the model file.
        robot: the arm the caller uses the model for; the file must record it (None: any robot).
        nominal: that arm's nominal geometry (robot YAML); the model's geometry must lie near it (see
            :func:`calibration.model_checks.check_model_for`).

    Raises:
        DataError: the file is missing, a folder, binary or not YAML/JSON; ModelFileError (a DataError) when a
            number is not finite, a rotation is not orthonormal with determinant +1, the method is unknown, a
            block is malformed, or the model is for another robot.
    """
    path = Path(path)
    data = _read_model_file(path)
    if data.get("schema") not in READABLE_SCHEMAS:
        raise DataError(path, None, None,
                        f"unsupported model schema {data.get('schema')!r}; expected one of {READABLE_SCHEMAS}")
    try:
        model_class(data.get("kind"))
    except ModelError as e:
        raise ModelFileError(path, "kind", str(e)) from e
    check_model_data(data, path)
    try:
        model = KinematicModel.from_dict(data)
    except ModelFileError as e:
        raise ModelFileError(path, e.key, e.reason) from e
    except KeyError as e:
        raise ModelFileError(path, str(e.args[0]), "missing") from e
    except (TypeError, ValueError, IndexError) as e:
        raise DataError(path, None, None, f"malformed model file: {e!r}") from e
    except ModelError as e:
        raise DataError(path, None, None, str(e)) from e
    check_model_numbers(_plain(model.to_dict()), path)  # every number again, after conversion
    R, p = model.fk(np.zeros((1, 6)))
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(p))) or not float(np.abs(p).max()) <= MAX_POSITION_MM:
        raise ModelFileError(path, "", f"the model's tool pose at q = 0 is {p[0].tolist()} mm: not a finite "
                                       f"position within {MAX_POSITION_MM:g} mm")
    if robot is not None:
        check_model_for(model, robot, nominal, path)
    return model
