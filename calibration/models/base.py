"""The model base, its registry and the model files.

Every model maps joint angles to the tool-marker pose, ``fk(q) -> (R (N, 3, 3), p (N, 3))``, and saves to
one versioned, human-readable file (``.yaml``/``.yml`` or ``.json``) that loads back to bit-identical
predictions (floats are written with their shortest exact repr). A file is checked when it is loaded (and a
model before it is saved) by :mod:`calibration.models.checks`: finite numbers, rotations, the recorded robot,
a known method, and each kind's own blocks; :func:`load_model` also checks it against the arm it is used for.

A model kind declares its parameter blocks once (:meth:`KinematicModel.blocks`, a tuple of :class:`Block`)
and from that declaration gives its pose, its parameter and joint Jacobians and its casadi expression
(:meth:`KinematicModel.casadi`). The kinds live next to this module: ``constant``, ``pi``, ``cdc``,
``physics``, ``diagnosed``, ``rebased``; each registers itself when its module is imported (:data:`KIND_MODULES`
says where, so loading a file imports the one it needs).
"""

from __future__ import annotations

import abc
import logging
from dataclasses import Field
from typing import TYPE_CHECKING, Any, ClassVar, Self

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.blocks import Block
from calibration.kinematics.casadi_expr import CasadiPose
from calibration.kinematics.poe import PoeModel
from calibration.models.registry import KINDS, model_class

#: The schema files are written with. /2 since the extrapolation guard's per-effect rule (the training region's
#: ``rule``): a cellcal that reads /1 only would load a /2 file's region, ignore its rule and predict up to 13 mm
#: differently with no warning, so it must refuse the file instead. /1 files are read as before.
SCHEMA = "cellcal.model/2"
#: The schemas this version reads.
READABLE_SCHEMAS = ("cellcal.model/1", SCHEMA)
log = logging.getLogger("cellcal.calibration")


class KinematicModel(abc.ABC):
    """A fitted model of one robot: joint angles in, tool-marker pose out."""

    kind: ClassVar[str]
    _registry: ClassVar[dict[str, type[KinematicModel]]] = {}
    robot: str
    method: str
    info: dict[str, Any]
    if TYPE_CHECKING:
        # Every model kind is a dataclass, so dataclasses.replace applies to any KinematicModel.
        __dataclass_fields__: ClassVar[dict[str, Field[Any]]]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "kind" in cls.__dict__:
            KINDS[cls.kind] = cls

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

    def with_region(self, region: Any) -> Self:
        """The same model with another training region (a :class:`calibration.models.guard.Region`, or None: none,
        which turns the extrapolation guard off)."""
        from dataclasses import replace

        from calibration.models.guard import REGION_KEY  # the guard loads when a region is asked for, not with a model

        info = {k: v for k, v in self.info.items() if k != REGION_KEY}
        return replace(self, info=info if region is None else {**info, REGION_KEY: region.to_dict()})

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

    def casadi(self, q: Any, theta: Any = None, q_at: Any = None) -> CasadiPose:
        """The pose as casadi expressions.

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
        """The constant geometry a URDF can hold and what it loses (a :class:`calibration.models.urdf.UrdfGeometry`).

        Raises:
            ModelError: this kind has no constant geometry to export.
        """
        raise ModelError(f"a {self.kind} model cannot be exported as a URDF; exportable kinds: "
                         "constant, pi, cdc, physics, diagnosed, rebased")

    def jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pose and ``d[p (mm); rotation (rad)] / d vector`` (N, 6, m) in the base frame.

        By default exact, from the model's own casadi expression; kinds with an analytic form override it.
        """
        from calibration.kinematics.casadi_expr import pose_jacobians  # the casadi path only when asked for

        R, p = self.fk(q)
        return R, p, pose_jacobians(lambda qs, ts: self.casadi(qs, ts), q, self.vector())[0]

    def jacobian_q(self, q: np.ndarray) -> np.ndarray:
        """``d[p (mm); rotation (rad)] / dq`` (N, 6, 6): exact, from the model's own casadi expression."""
        from calibration.kinematics.casadi_expr import pose_jacobians

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
        model: KinematicModel = model_class(kind)._from_body(d["robot"], d["method"], d.get("info", {}), d)
        return model


