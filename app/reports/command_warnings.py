"""Every warning a command gives, collected as it is given, so its report carries them all.

A command warns in two ways: a ``warning: ...`` line on stderr (the CLI's own checks: extrapolation, frames,
observability, gross rows, quaternion order ...) and a WARNING record on a ``cellcal`` logger (the library's).
:func:`collecting` (wrapped around every command by :func:`app.cli.commands.main`) tees ``sys.stderr`` and adds
a logging handler, and keeps both in one list. A report reads that list when it is rendered
(:func:`warnings_so_far`) and registers itself (:func:`register_page`); a warning given after a page was written
re-renders the page when the command ends, so a report never misses one, whatever the order of the code.
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, TextIO

#: The prefix of a warning line on stderr.
PREFIX = "warning: "


@dataclass
class Collector:
    """The warnings of one command run, in the order given, each once; and the pages rendered from them."""

    warnings: list[str] = field(default_factory=list)
    pages: list[tuple[int, Callable[[], Any]]] = field(default_factory=list)

    def add(self, text: str) -> None:
        text = " ".join(text.split())
        if text and text not in self.warnings:
            self.warnings.append(text)


_ACTIVE: list[Collector] = []


def warnings_so_far() -> list[str]:
    """The warnings given so far by the running command (empty outside :func:`collecting`)."""
    return list(_ACTIVE[-1].warnings) if _ACTIVE else []


def register_page(rewrite: Callable[[], Any]) -> None:
    """A page just rendered with :func:`warnings_so_far`: ``rewrite()`` renders it again if more come."""
    if _ACTIVE:
        _ACTIVE[-1].pages.append((len(_ACTIVE[-1].warnings), rewrite))


class _Tee:
    """``sys.stderr`` that passes everything on and keeps the ``warning: ...`` lines."""

    def __init__(self, stream: TextIO, collector: Collector) -> None:
        self._stream, self._collector, self._line = stream, collector, ""

    def write(self, s: str) -> int:
        if not self._line and s.startswith(PREFIX):  # one print(): the whole warning, also when it spans lines
            self._collector.add(s[len(PREFIX):])
            self._line = "" if s.endswith("\n") else "\0"  # "\0": inside a kept warning until its newline
            return self._stream.write(s)
        self._line += s
        *done, self._line = self._line.split("\n")
        for line in done:
            line = line.rsplit("\r", 1)[-1]  # a progress bar's carriage returns before a line
            if line.startswith(PREFIX):
                self._collector.add(line[len(PREFIX):])
        if len(self._line) > 100_000:  # a bar redrawn in place without a newline: no warning line in it
            self._line = self._line[-1000:]
        return self._stream.write(s)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


class _Handler(logging.Handler):
    def __init__(self, collector: Collector) -> None:
        super().__init__(logging.WARNING)
        self._collector = collector

    def emit(self, record: logging.LogRecord) -> None:
        if record.name.startswith("cellcal"):
            try:
                self._collector.add(record.getMessage())
            except Exception:  # noqa: BLE001 - logging must never raise (logging.Handler's contract)
                self.handleError(record)


@contextlib.contextmanager
def collecting() -> Iterator[Collector]:
    """Collect the warnings given inside the block; on leaving it, re-render the pages that missed some."""
    collector = Collector()
    stream, handler = sys.stderr, _Handler(collector)
    tee = _Tee(stream, collector)
    sys.stderr = tee
    logging.getLogger().addHandler(handler)
    _ACTIVE.append(collector)
    ok = False
    try:
        yield collector
        ok = True
    finally:
        logging.getLogger().removeHandler(handler)
        if sys.stderr is tee:
            sys.stderr = stream
        try:
            if ok:
                for seen, rewrite in collector.pages:
                    if seen < len(collector.warnings):
                        rewrite()
        finally:
            _ACTIVE.pop()
