"""Forward kinematics of every model kind as a casadi function, for planners that need exact Jacobians.

``casadi_fk(model)`` wraps the model's own expression, ``model.casadi(q)`` (every model kind, and a bare
:class:`~calibration.kinematics.poe.PoeModel`, provides one; see :mod:`calibration.kinematics.casadi_expr`), in a :class:`CasadiFk`
whose ``function`` maps ``(q (6,), x (k,))`` to the tool pose, the joint origins and axes. Every kind is exact
in q (``k = 0``): constant, pi, cdc with a casadi-expressible interpolator, physics and diagnosed (their joint
effects' deflection is part of the expression, so the planner differentiates through it). Only a ``cdc``
model whose interpolator casadi cannot see through (``cdc-frozen``) has ``k = m`` parameter inputs, which the
caller fixes at the previous iterate with ``params_at`` and solves again until they stop changing.

Also here: ``start_compile`` turns a casadi function into C once (gcc in the background, cached by a hash of
the source, the casadi version and the compiler; ``compile_function`` waits for it) and ``buffer_evaluator``
calls it without copies: together about 15x faster than the interpreted call.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import signal
import subprocess
import tempfile
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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


class Build:
    """A gcc build of one casadi function running in the background, into a private folder of the cache.

    :meth:`poll` returns the compiled function once gcc has finished (installing the library and its digest
    stamp atomically, so a concurrent build of the same key, or a crash, never leaves a half-written library),
    and None while it runs or after it failed. :meth:`cancel` kills gcc and removes its folder; a build still
    running when its owner is garbage-collected or the process exits is cancelled the same way.
    """

    def __init__(self, ca: Any, name: str, cc: str, src: str, lib: Path) -> None:
        self._ca, self.name, self.lib = ca, name, lib
        lib.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = Path(tempfile.mkdtemp(prefix=".build-", dir=lib.parent))
        c_file, self._out = self._tmp / "f.c", self._tmp / lib.name
        c_file.write_text(src)
        self._log = self._tmp / "gcc.log"
        try:
            with self._log.open("wb") as log:  # a file, not a pipe: gcc never blocks on a full pipe
                self._proc: subprocess.Popen[bytes] | None = subprocess.Popen(
                    [cc, *COMPILE_FLAGS, str(c_file), "-o", str(self._out), "-lm"],
                    stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=log,
                    start_new_session=True)  # its own process group: cancel kills cc1 and as too
        except OSError:
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise
        self._finalizer = weakref.finalize(self, _kill, self._proc, self._tmp)
        self.failed: str | None = None
        self._result: Any = None

    def poll(self) -> Any | None:
        """The compiled function if gcc has finished and the library is installed, else None (never blocks)."""
        if self._result is not None or self.failed is not None:
            return self._result
        if self._proc is not None and self._proc.poll() is None:
            return None
        return self._finish()

    def wait(self, timeout: float = 300.0) -> Any | None:
        """Block until gcc has finished (killing it after ``timeout`` s); the compiled function, or None."""
        if self._proc is not None and self._result is None and self.failed is None:
            try:
                self._proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.cancel(f"gcc took longer than {timeout:.0f} s")
                return None
        return self.poll()

    def cancel(self, why: str = "cancelled") -> None:
        """Kill gcc (if running) and remove its folder; the cache is left as it was."""
        if self._result is None and self.failed is None:
            self.failed = why
        self._finalizer()

    def _finish(self) -> Any | None:
        proc, self._proc = self._proc, None
        try:
            if proc is not None and proc.returncode != 0:
                err = self._log.read_text(errors="replace").strip()
                raise RuntimeError(f"gcc exited {proc.returncode}: {err[-300:]}")
            stamp = self._tmp / "stamp"
            stamp.write_text(_file_digest(self._out) + "\n")
            os.replace(self._out, self.lib)
            os.replace(stamp, self.lib.with_name(self.lib.name + ".sha256"))
            self._result = self._ca.external(self.name, str(self.lib))
            logger.info("compiled %s to %s", self.name, self.lib)
        except (OSError, RuntimeError) as e:
            self.failed = str(e)
            logger.warning("could not compile %s (%s); using the interpreted casadi function", self.name, e)
        finally:
            self._finalizer()
        return self._result


def _kill(proc: subprocess.Popen[bytes] | None, tmp: Path) -> None:
    """End a build: kill gcc and its compiler passes (cc1, as, ld: gcc's process group) if it still runs, remove
    its folder."""
    if proc is not None and proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()
    shutil.rmtree(tmp, ignore_errors=True)


def start_compile(ca: Any, F: Any, cache_dir: str | Path | None = None) -> tuple[Any, Build | None]:
    """F as fast as it can be had right now, and the build that will make it faster.

    Returns ``(compiled, None)`` when the library is in the cache (:func:`cache_key`), ``(F, build)`` when gcc
    has been started on it in the background (:class:`Build`), and ``(F, None)`` when it will not be compiled:
    no compiler, or more than :data:`MAX_COMPILE_INSTRUCTIONS` instructions (the build would take minutes).

    The cache lives in ``$CELLCAL_CACHE`` or ``~/.cache/cellcal``. Any change of the model's parameters changes
    the C source and so the key. A cached library whose bytes no longer match the digest stamped beside it at
    build time (truncated, overwritten, stamp missing) is built again.
    """
    try:
        size = int(F.n_instructions())
    except (AttributeError, RuntimeError, NotImplementedError):
        size = 0
    if size > MAX_COMPILE_INSTRUCTIONS:
        logger.info("%s has %d instructions (> %d): using the interpreted casadi function rather than a "
                    "minutes-long C build", F.name(), size, MAX_COMPILE_INSTRUCTIONS)
        return F, None
    cc = shutil.which(os.environ.get("CC", "gcc"))
    if cc is None:
        logger.info("no C compiler found; using the interpreted casadi function (slower)")
        return F, None
    cg = ca.CodeGenerator(f"{F.name()}.c", {"with_header": False})
    cg.add(F)
    src = cg.dump()
    root = Path(cache_dir or os.environ.get("CELLCAL_CACHE") or Path.home() / ".cache" / "cellcal")
    lib = root / f"{F.name()}_{cache_key(ca, src, cc)}.so"
    try:
        if _cached(lib):
            return ca.external(F.name(), str(lib)), None
        if lib.exists():
            logger.warning("cached %s does not match its build stamp (corrupt or incomplete); rebuilding it", lib)
        return F, Build(ca, F.name(), cc, src, lib)
    except (OSError, RuntimeError) as e:
        logger.warning("could not compile %s (%s); using the interpreted casadi function", F.name(), e)
        return F, None


def compile_function(ca: Any, F: Any, cache_dir: str | Path | None = None) -> Any:
    """F compiled to a shared library with gcc and cached (:func:`start_compile`), waiting for the build; F
    itself when it is not compiled or the build fails."""
    G, build = start_compile(ca, F, cache_dir)
    if build is None:
        return G
    compiled = build.wait()
    return F if compiled is None else compiled


def buffer_evaluator(F: Any, z: np.ndarray, out: np.ndarray) -> Callable[[], None]:
    """A zero-copy evaluator: reads ``z``, writes ``out`` in place."""
    try:
        buf, trigger = F.buffer()
        # numpy's stubs give ndarray __buffer__ only from Python 3.12 (mypy checks as 3.11)
        buf.set_arg(0, memoryview(z))  # type: ignore[arg-type]
        buf.set_res(0, memoryview(out))  # type: ignore[arg-type]
    except (AttributeError, NotImplementedError, RuntimeError):
        def run() -> None:
            out[:] = np.asarray(F(z)).ravel()
        return run

    def run_buffer() -> None:
        trigger()
        if buf is None:  # keeps the buffer (which owns the pointers) alive as long as the evaluator
            raise RuntimeError("casadi buffer released")
    return run_buffer
