"""Progress bars on stderr and log lines that do not break them: one policy for every long-running command.

* :func:`configure` is called once by the CLI: bars are on only when stderr is a terminal and ``--quiet`` was
  not given (a pipe or a log file gets no carriage-return noise).
* :func:`bar` is the one way workflows make a bar (a ``tqdm`` on stderr, off under that policy or when the caller
  passes ``enabled=False``).
* :class:`TqdmLoggingHandler` writes every log record through ``tqdm.write``, which clears the bars, prints the
  line and redraws them, so a warning logged during a bar ends up on a line of its own.
* :class:`EpochBar` turns the ``progress(epoch, n_epochs)`` callback of the neural interpolators' training
  (``calibration.interpolation``, which knows nothing of bars) into a bar.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterable
from typing import Any, TextIO

_state = {"enabled": True}


def configure(quiet: bool = False, stream: TextIO | None = None) -> bool:
    """Set whether bars are shown: not with ``quiet``, and only when ``stream`` (stderr) is a terminal.

    Returns:
        Whether bars are now on.
    """
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    _state["enabled"] = not quiet and bool(isatty and isatty())
    return _state["enabled"]


def enabled() -> bool:
    """Whether bars are on (the policy set by :func:`configure`)."""
    return _state["enabled"]


def bar(iterable: Iterable[Any] | None = None, *, enabled: bool = True, file: TextIO | None = None,
        **kwargs: Any) -> Any:
    """A tqdm bar on stderr (``file``), disabled unless both the policy and ``enabled`` allow it."""
    from tqdm import tqdm

    on = enabled and _state["enabled"]
    return tqdm(iterable, file=sys.stderr if file is None else file, disable=not on, dynamic_ncols=True, **kwargs)


class TqdmLoggingHandler(logging.Handler):
    """A logging handler that prints through ``tqdm.write`` so records never land in the middle of a bar."""

    def __init__(self, stream: TextIO | None = None, level: int = logging.NOTSET) -> None:
        super().__init__(level)
        self.stream = stream

    def emit(self, record: logging.LogRecord) -> None:
        from tqdm import tqdm

        try:
            tqdm.write(self.format(record), file=sys.stderr if self.stream is None else self.stream)
        except Exception:  # noqa: BLE001 - logging must never raise (logging.Handler's contract)
            self.handleError(record)


def install_logging(level: int, stream: TextIO | None = None) -> TqdmLoggingHandler:
    """Route the root logger through a :class:`TqdmLoggingHandler` at ``level`` (replacing earlier handlers)."""
    handler = TqdmLoggingHandler(stream)
    handler.setFormatter(logging.Formatter("%(message)s"))
    root = logging.getLogger()
    for h in list(root.handlers):
        if isinstance(h, TqdmLoggingHandler):
            root.removeHandler(h)
    root.addHandler(handler)
    root.setLevel(level)
    return handler


class EpochBar:
    """A ``progress(epoch, n_epochs)`` callback that draws one bar per training run (restarted at epoch 1).

    Args:
        desc: the bar's label.
        enabled: False for no bar at all (the policy of :func:`configure` applies too).
    """

    def __init__(self, desc: str, enabled: bool = True) -> None:
        self.desc = desc
        self.on = enabled
        self._bar: Any = None
        self.runs = 0

    def __call__(self, epoch: int, n_epochs: int) -> None:
        if epoch == 1:
            self.close()
            self.runs += 1
            self._bar = bar(total=n_epochs, enabled=self.on, desc=f"{self.desc} {self.runs}", unit="epoch",
                            leave=False)
        if self._bar is not None:
            self._bar.update(1)
            if epoch >= n_epochs:
                self.close()

    def close(self) -> None:
        """Close the current bar (idempotent)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
