"""The ``cellcal`` command line: the parser and the analysis commands (:mod:`app.cli.commands`, holding
:func:`main`), the cell commands (:mod:`~app.cli.cell`: plan, collect, export, register, ...), the dual-cell
commands (:mod:`~app.cli.dual`: plan-dual, export-targets, preview, validate-dual), the real-cell tools
(:mod:`~app.cli.real`: controller checks, fake Motive), the motion and ``--sim`` options
(:mod:`~app.cli.cell_options`) and the helpers they share (:mod:`~app.cli.common`).

Only this package reads ``argparse`` namespaces; the workflows it calls take plain arguments.
``python -m app.cli`` and the ``cellcal`` console script both run :func:`main`.
"""

import os

# One BLAS thread unless the caller says otherwise (before numpy loads). The products here are small (an LM
# normal matrix of 10^4 x 30, 200-wide layers), so a second BLAS thread mostly adds synchronisation, and its
# spin-wait takes the core the held-out workers of compare need; on a shared 2-core machine every threaded
# call also stalls until both threads are scheduled (measured: diagnose 10.4 s of CPU with two threads, 2.6 s
# with one, same results).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from app.cli.commands import main  # noqa: E402

__all__ = ["main"]
