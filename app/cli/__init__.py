"""The ``cellcal`` command line: the parser and the analysis commands (:mod:`app.cli.commands`, holding
:func:`main`), the cell commands (:mod:`~app.cli.cell`: plan, collect, export, register, ...), the dual-cell
commands (:mod:`~app.cli.dual`: plan-dual, export-targets, preview, validate-dual), the real-cell tools
(:mod:`~app.cli.real`: controller checks, fake Motive), the motion and ``--sim`` options
(:mod:`~app.cli.cell_options`) and the helpers they share (:mod:`~app.cli.common`).

Only this package reads ``argparse`` namespaces; the workflows it calls take plain arguments.
``python -m app.cli`` and the ``cellcal`` console script both run :func:`main`.
"""

from app.cli.commands import main

__all__ = ["main"]
