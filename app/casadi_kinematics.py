"""Forward kinematics of every model kind as casadi functions, for planners that need exact Jacobians.

``casadi_fk(model)`` returns a :class:`CasadiFk` whose ``function`` maps ``(q (6,), x (k,))`` to the tool
pose, the joint origins and axes, all as casadi expressions of ``q``:

* ``ConstantModel`` (or a bare :class:`~calibration.poe.PoeModel`): the POE chain, ``k = 0``.
* ``PhysicsInformedModel`` (kind ``pi``): geometry, tool rotation, gravity compliance and structural deflection
  written out in casadi (:func:`extended_sx`); ``k = 0``.
* ``CdcModel`` whose interpolator is casadi-expressible: the geometric parameters are casadi expressions of the
  interpolator inputs (q2, q3), the other terms of its reference model constants, so derivatives include the
  parameters' dependence on q; ``k = 0``.
  Expressible means the interpolator has ``casadi_predict(x_sx) -> SX (m,)`` (the Fourier kinds
  ``fbf13``/``fbf7`` do), or ``basis(x) (N, r)`` written with numpy ufuncs plus ``coefficients`` (r, m);
  either is checked against ``interpolator.predict`` at random inputs before it is trusted.
* Any other ``CdcModel``: the parameters are an input ``x`` (``k = m``, ``frozen = True``). The caller
  evaluates ``params_at(q)`` with numpy at the previous iterate and solves again until they stop changing
  (a fixed point; it converges because the parameters vary by micro-radians per radian of q2, q3).
* ``compile_function`` turns a casadi function into C once (gcc, cached by source hash) and
  ``buffer_evaluator`` calls it without copies: together about 50x faster than the interpreted call.
* Models with a joint-space effect ``q -> q + dq(q)``: pass ``dq`` (a casadi Function (6,) -> (6,)) or give
  the model a ``casadi_dq()`` method; the chain is evaluated at ``q + dq(q)``.
* ``PhysicsModel`` (geometry + effects) without such a hook: its joint effects' ``dq`` at the default context
  becomes the frozen input (``k = 6``, kind ``physics-frozen``), solved by the same fixed point as above
  (gravity sag changes by micro-radians per radian). Geometry effects that change the links at the default
  context cannot be expressed and are refused, never dropped.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from calibration.cdc import CdcModel
from calibration.errors import ModelError
from calibration.parameterisation import MinimalParameterisation
from calibration.physics_informed import DEFLECTION_TERMS, ExtendedKinematics, PhysicsInformedModel
from calibration.poe import PoeModel

logger = logging.getLogger("cellcal.app")


@dataclass(frozen=True)
class CasadiFk:
    """A model's forward kinematics as a casadi function.

    Attributes:
        function: ``(q (6,), x (k,)) -> (R_base_tool (3, 3), p_base_tool (3,) [mm], origins (3, 7) [mm],
            axes (3, 6))``; ``origins`` are the joint-axis points and the flange point (the arm's skeleton,
            for capsules), ``axes`` the joint axes, all in the base frame.
        n_frozen: k, the size of the frozen-parameter input (0 when the model is fully casadi-expressible).
        params_at: for frozen models, ``q (6,) -> x (k,)`` evaluated with numpy; None otherwise.
        kind: model kind (``constant``, ``cdc``, ``cdc-frozen``, ``poe``), with ``+dq`` when a dq hook is used.
    """

    function: Any
    n_frozen: int = 0
    params_at: Callable[[np.ndarray], np.ndarray] | None = None
    kind: str = "constant"

    @property
    def frozen(self) -> bool:
        return self.n_frozen > 0

    def x0(self, q: np.ndarray) -> np.ndarray:
        """The frozen-parameter input for joint angles q [rad] (6,); empty for exact models."""
        return np.zeros(0) if self.params_at is None else np.asarray(self.params_at(q), dtype=float)


def _rot(ca: Any, h: Any, q: Any) -> Any:
    K = ca.skew(h)
    return ca.SX.eye(3) + ca.sin(q) * K + (1 - ca.cos(q)) * (K @ K)


def poe_chain(ca: Any, model: PoeModel, q: Any, H: Any = None, P: Any = None) -> tuple[Any, Any, Any, Any]:
    """POE forward kinematics on casadi symbols, same convention as :meth:`PoeModel.chain`.

    Returns:
        ``(R_base_tool (3, 3), p_base_tool (3,), origins (3, n+1), axes (3, n))`` as casadi SX.
    """
    n = model.n_joints
    H = ca.DM(model.H) if H is None else H
    P = ca.DM(model.P) if P is None else P
    R = ca.SX.eye(3)
    p = ca.SX(P[:, 0])
    origins = [p]
    axes = []
    for i in range(n):
        axes.append(R @ H[:, i])
        R = R @ _rot(ca, H[:, i], q[i])
        p = p + R @ P[:, i + 1]
        origins.append(p)
    return (R @ ca.DM(model.R_6_tool), p + R @ ca.DM(model.p_6_tool), ca.horzcat(*origins),
            ca.horzcat(*axes))


def geometry_sx(ca: Any, par: MinimalParameterisation, x: Any) -> tuple[Any, Any]:
    """casadi version of :meth:`MinimalParameterisation.geometry` for one parameter vector x (m,)."""
    n = par.n_joints
    Hn, Pn = par.nominal.H, par.nominal.P
    hs, dO = [], []
    for j in range(n):
        k1, k2 = ca.DM(par.k1[j]), ca.DM(par.k2[j])
        v = _rot(ca, k1, x[2 * n + 2 * j]) @ ca.DM(Hn[:, j])
        hs.append(_rot(ca, k2, x[2 * n + 2 * j + 1]) @ v)
        dO.append(x[2 * j] * k1 + x[2 * j + 1] * k2)
    tool = x[4 * n: 4 * n + 3] if par.fit_tool else ca.SX.zeros(3)
    cols = [ca.DM(Pn[:, 0]) + dO[0]]
    cols += [ca.DM(Pn[:, i]) + dO[i] - dO[i - 1] for i in range(1, n)]
    cols.append(ca.DM(Pn[:, n]) + tool - dO[n - 1])
    return ca.horzcat(*hs), ca.horzcat(*cols)


MAX_SERIES_ANGLE_RAD = 0.2


def exp_sx(ca: Any, w: Any) -> Any:
    """Rotation matrix of a small rotation vector w (3,) by the Rodrigues series, exact to machine precision
    for |w| < 0.2 rad (no division, so derivatives stay finite at w = 0)."""
    t2 = ca.dot(w, w)
    a = 1 - t2 / 6 + t2**2 / 120 - t2**3 / 5040 + t2**4 / 362880
    b = 0.5 - t2 / 24 + t2**2 / 720 - t2**3 / 40320 + t2**4 / 3628800
    K = ca.skew(w)
    return ca.SX.eye(3) + a * K + b * (K @ K)


def extended_sx(ca: Any, kin: ExtendedKinematics, q: Any, theta: Any) -> tuple[Any, Any, Any, Any]:
    """casadi version of :meth:`ExtendedKinematics.pose` (plus the skeleton) for one parameter vector.

    Returns:
        ``(R_base_tool, p_base_tool, origins (3, n+1), axes (3, n))`` with the deflection applied to all of them.
    """
    g, t, c, _ = kin.sizes
    x, w_tool, cc = theta[:g], theta[g:g + t], theta[g + t:g + t + c]
    off = g + t + c
    u = q[1] - q[2]
    dq = ca.vertcat(0, cc[0] * ca.sin(q[1]) + cc[1] * ca.cos(u) + cc[2] * ca.sin(u),
                    cc[3] * ca.cos(u) + cc[4] * ca.sin(u), 0, 0, 0)
    H, P = geometry_sx(ca, kin.par, x)
    R0, p0, O, A = poe_chain(ca, kin.par.nominal, q + dq, H, P)
    R0 = R0 @ exp_sx(ca, w_tool)
    F = [1, ca.sin(q[1]), ca.sin(q[2]), ca.cos(q[1]), ca.cos(q[2]), ca.sin(q[1] + q[2]), ca.cos(q[1] + q[2])]
    xi = [sum(F[k] * theta[off + 6 * k + j] for k in range(len(DEFLECTION_TERMS))) for j in range(6)]
    Rz = _rot(ca, ca.DM([0.0, 0.0, 1.0]), q[0])
    E = exp_sx(ca, Rz @ ca.vertcat(*xi[3:]))
    shift = Rz @ ca.vertcat(*xi[:3])
    O = E @ O + ca.repmat(shift, 1, O.shape[1])
    return E @ R0, E @ p0 + shift, O, E @ A


def _check_small_rotations(kin: ExtendedKinematics, theta: np.ndarray) -> None:
    g, t, c, _ = kin.sizes
    C = theta[g + t + c:].reshape(len(DEFLECTION_TERMS), 6)
    bound = max(np.linalg.norm(theta[g:g + t]), float(np.abs(C[:, 3:]).sum(axis=0).max()) * np.sqrt(3))
    if bound >= MAX_SERIES_ANGLE_RAD:
        raise ModelError(f"tool or deflection rotation up to {bound:.3f} rad exceeds the {MAX_SERIES_ANGLE_RAD} rad "
                         "the casadi kinematics are exact for")


def interpolator_sx(ca: Any, interp: Any, u: Any, m: int, check_seed: int = 0) -> Any | None:
    """The interpolator's prediction as a casadi expression of its inputs u (d,), or None if not expressible.

    Tries ``interp.casadi_predict(u)``, then ``interp.basis(u) @ coefficients`` through numpy object arrays;
    the result is compared with ``interp.predict`` at 5 random inputs (atol 1e-12) before it is accepted.
    """
    d = u.shape[0]
    expr = None
    try:
        if hasattr(interp, "casadi_predict"):
            expr = ca.reshape(interp.casadi_predict(u), m, 1)
        elif hasattr(interp, "basis") and hasattr(interp, "coefficients"):
            C = interp.coefficients() if callable(interp.coefficients) else interp.coefficients
            uo = np.array([[u[i] for i in range(d)]], dtype=object)
            B = np.asarray(interp.basis(uo), dtype=object) @ np.asarray(C, dtype=float)
            expr = ca.vertcat(*[ca.SX(B[0, i]) for i in range(m)])
    except Exception as e:  # any failure means "not expressible": fall back to frozen parameters
        logger.info("interpolator %s is not casadi-expressible (%s); using frozen parameters",
                    getattr(interp, "kind", type(interp).__name__), e)
        return None
    if expr is None:
        return None
    f = ca.Function("interp", [u], [expr])
    rng = np.random.default_rng(check_seed)
    xs = rng.uniform(-1.0, 1.0, (5, d))
    got = np.array([np.asarray(f(xi)).ravel() for xi in xs])
    if not np.allclose(got, interp.predict(xs), rtol=0.0, atol=1e-12):
        logger.warning("casadi form of interpolator %s disagrees with predict(); using frozen parameters",
                       getattr(interp, "kind", type(interp).__name__))
        return None
    return expr


def casadi_fk(model: Any, dq: Any = None) -> CasadiFk:
    """Build the casadi forward kinematics of a model.

    Args:
        model: ``ConstantModel``, ``CdcModel``, a bare ``PoeModel``, or any object with ``casadi_fk()``
            returning a :class:`CasadiFk`.
        dq: optional casadi Function ``q (6,) -> dq (6,)`` [rad]; the chain is evaluated at ``q + dq(q)``.
            Defaults to ``model.casadi_dq()`` when the model has one.

    Returns:
        The :class:`CasadiFk`.

    Raises:
        ModelError: the model kind cannot be expressed.
    """
    import casadi as ca

    if hasattr(model, "casadi_fk"):
        return model.casadi_fk()
    if dq is None and hasattr(model, "casadi_dq"):
        dq = model.casadi_dq()
    if dq is None and hasattr(model, "effects") and isinstance(getattr(model, "model", None), PoeModel):
        return _physics_fk(ca, model)
    q = ca.SX.sym("q", 6)
    q_chain = q if dq is None else q + dq(q)
    suffix = "" if dq is None else "+dq"
    if isinstance(model, PoeModel) or hasattr(model, "model") and isinstance(model.model, PoeModel):
        poe = model if isinstance(model, PoeModel) else model.model
        x = ca.SX.sym("x", 0)
        R, p, O, A = poe_chain(ca, poe, q_chain)
        f = ca.Function("fk", [q, x], [R, p, O, A], ["q", "x"], ["R", "p", "origins", "axes"])
        return CasadiFk(f, 0, None, ("poe" if isinstance(model, PoeModel) else "constant") + suffix)
    if isinstance(model, PhysicsInformedModel):
        _check_small_rotations(model.kinematics, model.theta)
        R, p, O, A = extended_sx(ca, model.kinematics, q_chain, ca.DM(model.theta))
        f = ca.Function("fk", [q, ca.SX.sym("x", 0)], [R, p, O, A], ["q", "x"], ["R", "p", "origins", "axes"])
        return CasadiFk(f, 0, None, "pi" + suffix)
    if isinstance(model, CdcModel):
        kin = model.kinematics
        g = kin.par.size
        _check_small_rotations(kin, model.theta_ref)
        inputs = list(model.inputs)
        u = ca.SX.sym("u", len(inputs))
        expr = interpolator_sx(ca, model.interpolator, u, g)
        rest = ca.DM(model.theta_ref[g:])
        if expr is not None:
            xq = ca.substitute(expr, u, ca.vertcat(*[q[i] for i in inputs]))
            R, p, O, A = extended_sx(ca, kin, q_chain, ca.vertcat(xq, rest))
            f = ca.Function("fk", [q, ca.SX.sym("x", 0)], [R, p, O, A], ["q", "x"],
                            ["R", "p", "origins", "axes"])
            return CasadiFk(f, 0, None, "cdc" + suffix)
        x = ca.SX.sym("x", g)
        R, p, O, A = extended_sx(ca, kin, q_chain, ca.vertcat(x, rest))
        f = ca.Function("fk", [q, x], [R, p, O, A], ["q", "x"], ["R", "p", "origins", "axes"])
        return CasadiFk(f, g, lambda qq: model.parameters_at(np.asarray(qq)[None])[0, :g], "cdc-frozen" + suffix)
    raise ModelError(f"cannot build casadi kinematics for {type(model).__name__} "
                     f"(kind {getattr(model, 'kind', '?')!r}); supported: constant, cdc, pi, physics, "
                     "PoeModel, or a model with casadi_fk()")


def _physics_fk(ca: Any, model: Any) -> CasadiFk:
    """Frozen-dq kinematics of a model with effects: the chain at ``q + x``, ``x = sum of effects' dq(q)``."""
    poe: PoeModel = model.model
    for e in model.effects:
        if e.target != "joints":
            P = e.geometry(poe, 1, None)
            if not np.allclose(P[0], poe.P, rtol=0.0, atol=1e-12):
                raise ModelError(f"cannot build casadi kinematics for a physics model with the geometry effect "
                                 f"{e.kind!r} active at the default context; supported: joint effects")
    joint_effects = [e for e in model.effects if e.target == "joints"]
    q, x = ca.SX.sym("q", 6), ca.SX.sym("x", 6)
    R, p, O, A = poe_chain(ca, poe, q + x)
    f = ca.Function("fk", [q, x], [R, p, O, A], ["q", "x"], ["R", "p", "origins", "axes"])

    def dq_at(qq: np.ndarray) -> np.ndarray:
        qq = np.asarray(qq, dtype=float)[None]
        return sum((e.delta_q(poe, qq, None)[0] for e in joint_effects), np.zeros(6))

    return CasadiFk(f, 6, dq_at, "physics-frozen")


def compile_function(ca: Any, F: Any, cache_dir: str | Path | None = None) -> Any:
    """F compiled to a shared library with gcc, cached by the hash of its C source; F itself on failure.

    The cache lives in ``$CELLCAL_CACHE`` or ``~/.cache/cellcal`` so only the first build of a given model pays
    the compile time (seconds); later builds load the library in milliseconds.
    """
    cc = shutil.which(os.environ.get("CC", "gcc"))
    if cc is None:
        logger.info("no C compiler found; using the interpreted casadi function (slower)")
        return F
    cg = ca.CodeGenerator(f"{F.name()}.c", {"with_header": False})
    cg.add(F)
    src = cg.dump()
    digest = hashlib.sha256(src.encode()).hexdigest()[:16]
    root = Path(cache_dir or os.environ.get("CELLCAL_CACHE") or Path.home() / ".cache" / "cellcal")
    lib = root / f"{F.name()}_{digest}.so"
    try:
        if not lib.exists():
            root.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(dir=root) as tmp:
                c_file = Path(tmp) / f"{F.name()}.c"
                c_file.write_text(src)
                out = Path(tmp) / lib.name
                subprocess.run([cc, "-O1", "-fPIC", "-shared", str(c_file), "-o", str(out), "-lm"],
                               check=True, capture_output=True, timeout=300)
                os.replace(out, lib)
            logger.info("compiled %s to %s", F.name(), lib)
        return ca.external(F.name(), str(lib))
    except (OSError, subprocess.SubprocessError, RuntimeError) as e:
        logger.warning("could not compile %s (%s); using the interpreted casadi function", F.name(), e)
        return F


def buffer_evaluator(F: Any, z: np.ndarray, out: np.ndarray) -> Callable[[], None]:
    """A zero-copy evaluator: reads ``z``, writes ``out`` in place."""
    try:
        buf, trigger = F.buffer()
        buf.set_arg(0, memoryview(z))
        buf.set_res(0, memoryview(out))
    except (AttributeError, NotImplementedError, RuntimeError):
        def run() -> None:
            out[:] = np.asarray(F(z)).ravel()
        return run

    def run_buffer() -> None:
        trigger()
        if buf is None:  # keeps the buffer (which owns the pointers) alive as long as the evaluator
            raise RuntimeError("casadi buffer released")
    return run_buffer
