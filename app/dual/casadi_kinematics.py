"""Forward kinematics of every model kind as a casadi function, for planners that need exact Jacobians.

``casadi_fk(model)`` wraps the model's own expression, ``model.casadi(q)`` (every model kind, and a bare
:class:`~calibration.poe.PoeModel`, provides one; see :mod:`calibration.casadi_expr`), in a :class:`CasadiFk`
whose ``function`` maps ``(q (6,), x (k,))`` to the tool pose, the joint origins and axes. Every kind is exact
in q (``k = 0``): constant, pi, cdc with a casadi-expressible interpolator, physics and diagnosed (their joint
effects' deflection is part of the expression, so the planner differentiates through it). Only a ``cdc``
model whose interpolator casadi cannot see through (``cdc-frozen``) has ``k = m`` parameter inputs, which the
caller fixes at the previous iterate with ``params_at`` and solves again until they stop changing.

Also here: ``compile_function`` turns a casadi function into C once (gcc, cached by a hash of the source, the
casadi version and the compiler) and ``buffer_evaluator`` calls it without copies: together about 15x faster
than the interpreted call.
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

from calibration.errors import ModelError

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
        kind: the expression's kind (``constant``, ``pi``, ``cdc``, ``cdc-frozen``, ``physics``, ``diagnosed``,
            ``poe``), with ``+dq`` when a dq hook is used.
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


def casadi_fk(model: Any, dq: Any = None) -> CasadiFk:
    """Build the casadi forward kinematics of a model from its own expression (``model.casadi``).

    Args:
        model: any model kind (``constant``, ``cdc``, ``pi``, ``physics``, ``diagnosed``) or a bare ``PoeModel``.
        dq: optional casadi Function ``q (6,) -> dq (6,)`` [rad]; the kinematics are evaluated at ``q + dq(q)``
            (configuration-dependent parameters still at q).

    Returns:
        The :class:`CasadiFk`.

    Raises:
        ModelError: the model has no casadi expression.
    """
    import casadi as ca

    build = getattr(model, "casadi", None)
    if build is None:
        raise ModelError(f"cannot build casadi kinematics for {type(model).__name__}: it has no casadi() "
                         "expression; supported: constant, cdc, pi, physics, diagnosed models and PoeModel")
    q = ca.SX.sym("q", 6)
    e = build(q if dq is None else q + dq(q), q_at=q)
    x = ca.SX.sym("x", 0) if e.frozen is None else e.frozen
    f = ca.Function("fk", [q, x], [e.R, e.p, e.origins, e.axes], ["q", "x"], ["R", "p", "origins", "axes"])
    return CasadiFk(f, int(x.numel()), e.frozen_at, e.kind + ("" if dq is None else "+dq"))


#: Largest casadi function (SX instructions) :func:`compile_function` hands to gcc. CDC models on piecewise
#: interpolators (linear, cubic: an if_else chain over every simplex) or big networks write functions of
#: 1e5-1e6 instructions whose -O1 build takes minutes (measured: 56k ~10 s, 371k > 60 s on the 2-core box);
#: interpreted they still evaluate in about a millisecond.
MAX_COMPILE_INSTRUCTIONS = 100_000


#: gcc flags of the cached build. -O0 compiles the planner's function (25k instructions) in half the time of -O1
#: (measured 3.5 s against 7.5 s on the loaded 2-core box) and evaluates it in 15 us instead of 5 us, which a
#: 200-waypoint plan (about 1000 evaluations) does not notice; interpreted it takes ~250 us.
COMPILE_FLAGS = ("-O0", "-fPIC", "-shared")


def cache_key(ca: Any, src: str, cc: str) -> str:
    """Hash of what the compiled library depends on: the C source (the expression, every model parameter in it
    as a constant), the casadi version that wrote and will load it, the compiler and its flags."""
    h = hashlib.sha256()
    for part in (src, ca.__version__, cc, *COMPILE_FLAGS):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()[:16]


def _file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _cached(lib: Path) -> bool:
    """Whether ``lib`` is a complete build: its bytes match the digest written beside it after the build (a
    truncated or overwritten library would crash the process when loaded, not raise)."""
    stamp = lib.with_name(lib.name + ".sha256")
    try:
        return lib.exists() and stamp.read_text().strip() == _file_digest(lib)
    except OSError:
        return False


def _build(cc: str, src: str, lib: Path) -> None:
    """Compile src into lib (atomically), then write its digest stamp."""
    lib.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=lib.parent) as tmp:
        c_file = Path(tmp) / "f.c"
        c_file.write_text(src)
        out, stamp = Path(tmp) / lib.name, Path(tmp) / "stamp"
        subprocess.run([cc, *COMPILE_FLAGS, str(c_file), "-o", str(out), "-lm"], check=True, capture_output=True,
                       timeout=300)
        stamp.write_text(_file_digest(out) + "\n")
        os.replace(out, lib)
        os.replace(stamp, lib.with_name(lib.name + ".sha256"))


def compile_function(ca: Any, F: Any, cache_dir: str | Path | None = None) -> Any:
    """F compiled to a shared library with gcc, cached by :func:`cache_key`; F itself on failure, or when F has
    more than :data:`MAX_COMPILE_INSTRUCTIONS` instructions (the build would take minutes).

    The cache lives in ``$CELLCAL_CACHE`` or ``~/.cache/cellcal`` so only the first build of a given model pays
    the compile time (about a second); later builds load the library in milliseconds. Any change of the model's
    parameters changes the C source and so the key. A cached library whose bytes no longer match the digest
    stamped beside it at build time (truncated, overwritten, stamp missing) is rebuilt.
    """
    try:
        size = int(F.n_instructions())
    except (AttributeError, RuntimeError, NotImplementedError):
        size = 0
    if size > MAX_COMPILE_INSTRUCTIONS:
        logger.info("%s has %d instructions (> %d): using the interpreted casadi function rather than a "
                    "minutes-long C build", F.name(), size, MAX_COMPILE_INSTRUCTIONS)
        return F
    cc = shutil.which(os.environ.get("CC", "gcc"))
    if cc is None:
        logger.info("no C compiler found; using the interpreted casadi function (slower)")
        return F
    cg = ca.CodeGenerator(f"{F.name()}.c", {"with_header": False})
    cg.add(F)
    src = cg.dump()
    root = Path(cache_dir or os.environ.get("CELLCAL_CACHE") or Path.home() / ".cache" / "cellcal")
    lib = root / f"{F.name()}_{cache_key(ca, src, cc)}.so"
    try:
        if not _cached(lib):
            if lib.exists():
                logger.warning("cached %s does not match its build stamp (corrupt or incomplete); rebuilding it", lib)
            _build(cc, src, lib)
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
