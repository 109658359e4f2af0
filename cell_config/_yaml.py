"""Typed reading of parsed YAML mappings; every error names the file, the dotted key and what was expected.

Shared by the cell, robot, tool and registration loaders. YAML's own coercions are not trusted: a boolean
must be a YAML boolean (the string ``"false"`` is an error, not True), an integer must be an int (not a
bool, not a float), a number must be an int or a float (not a bool, not a string) and finite.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any, TypeVar, overload

import numpy as np
import yaml

from calibration.data.files import InputRefused, read_input_text
from calibration.data.yamlio import safe_load
from calibration.errors import ConfigError, parse_error_text

_REQUIRED: Any = ...
_T = TypeVar("_T")  # a getter's default, returned as is when the key is absent


def read_yaml(path: Path) -> Any:
    """Parse ``path`` as ``yaml.safe_load`` does; a missing file or bad YAML is a ConfigError."""
    try:
        return safe_load(read_input_text(path))  # libyaml, as model files are read; a regular file, bounded
    except FileNotFoundError as e:
        raise ConfigError(path, "", "file not found") from e
    except IsADirectoryError as e:
        raise ConfigError(path, "", "expected a file, found a directory") from e
    except yaml.YAMLError as e:
        raise ConfigError(path, "", f"not valid YAML ({parse_error_text(e)})") from e
    except InputRefused as e:  # a FIFO, a device, a file over the bound
        raise ConfigError(path, "", str(e.strerror)) from None  # strerror: the reason InputRefused was given
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(path, "", f"cannot read ({e.__class__.__name__}: {e})") from e


class Node:
    """One mapping of a YAML file, with typed getters that raise ConfigError(path, dotted.key, reason).

    Args:
        path: the file (for messages).
        data: the parsed mapping.
        key: dotted key of this mapping inside the file, ``""`` for the top level.
    """

    def __init__(self, path: Path, data: Any, key: str = "") -> None:
        self.path = path
        self.key = key
        if not isinstance(data, dict):
            raise ConfigError(path, key, "expected a mapping" + ("" if key else " at the top level"))
        self.data = data

    @classmethod
    def load(cls, path: str | Path) -> Node:
        """The top-level mapping of the YAML file at ``path``."""
        return cls(Path(path), read_yaml(Path(path)))

    def dotted(self, key: str) -> str:
        return f"{self.key}.{key}" if self.key else str(key)

    def error(self, key: str, reason: str) -> ConfigError:
        return ConfigError(self.path, self.dotted(key), reason)

    def __contains__(self, key: str) -> bool:
        return key in self.data

    def only(self, valid: Iterable[str]) -> None:
        """Refuse keys outside ``valid`` (the message lists the valid keys)."""
        valid = tuple(valid)
        for key in self.data:
            if key not in valid:
                where = self.key or "the top level"
                raise ConfigError(self.path, self.dotted(str(key)),
                                  f"unknown key in {where}; valid keys: {', '.join(valid)}")

    def get(self, key: str, default: Any = _REQUIRED) -> Any:
        if key not in self.data:
            if default is _REQUIRED:
                raise self.error(key, "required key is missing")
            return default
        return self.data[key]

    @overload
    def child(self, key: str) -> Node: ...
    @overload
    def child(self, key: str, default: None) -> Node | None: ...

    def child(self, key: str, default: Any = _REQUIRED) -> Node | None:
        """The mapping under ``key`` (None when absent and ``default`` is None)."""
        value = self.get(key, default)
        if value is None and key not in self.data:
            return None
        return Node(self.path, value, self.dotted(key))

    @overload
    def string(self, key: str) -> str: ...
    @overload
    def string(self, key: str, default: _T) -> str | _T: ...

    def string(self, key: str, default: Any = _REQUIRED) -> object:
        value = self.get(key, default)
        if key not in self.data:
            return value
        if not isinstance(value, str) or not value.strip():
            raise self.error(key, f"expected a non-empty string, got {value!r}")
        return value

    @overload
    def boolean(self, key: str) -> bool: ...
    @overload
    def boolean(self, key: str, default: _T) -> bool | _T: ...

    def boolean(self, key: str, default: Any = _REQUIRED) -> object:
        value = self.get(key, default)
        if key in self.data and not isinstance(value, bool):
            raise self.error(key, f"expected a YAML boolean (true or false, unquoted), got {value!r}")
        return value

    @overload
    def integer(self, key: str, *, lo: int | None = None, hi: int | None = None) -> int: ...
    @overload
    def integer(self, key: str, default: _T, lo: int | None = None, hi: int | None = None) -> int | _T: ...

    def integer(self, key: str, default: Any = _REQUIRED, lo: int | None = None, hi: int | None = None) -> object:
        value = self.get(key, default)
        if key not in self.data:
            return value
        span = _span(lo, hi)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"expected an integer{span}, got {value!r}")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise self.error(key, f"expected an integer{span}, got {value}")
        return value

    @overload
    def port(self, key: str) -> int: ...
    @overload
    def port(self, key: str, default: _T) -> int | _T: ...

    def port(self, key: str, default: Any = _REQUIRED) -> object:
        return self.integer(key, default, 1, 65535)

    @overload
    def number(self, key: str, *, lo: float | None = None, hi: float | None = None, lo_open: bool = False) -> float: ...
    @overload
    def number(self, key: str, default: _T, lo: float | None = None, hi: float | None = None,
               lo_open: bool = False) -> float | _T: ...

    def number(self, key: str, default: Any = _REQUIRED, lo: float | None = None, hi: float | None = None,
               lo_open: bool = False) -> object:
        """A finite int or float within [lo, hi] (or (lo, hi] with ``lo_open``)."""
        value = self.get(key, default)
        if key not in self.data:
            return value
        span = _span(lo, hi, lo_open)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.error(key, f"expected a finite number{span}, got {value!r}")
        low_bad = lo is not None and (value <= lo if lo_open else value < lo)
        if low_bad or (hi is not None and value > hi):
            raise self.error(key, f"expected a finite number{span}, got {value!r}")
        return float(value)

    @overload
    def array(self, key: str, shape: tuple[int, ...]) -> np.ndarray: ...
    @overload
    def array(self, key: str, shape: tuple[int, ...], default: _T) -> np.ndarray | _T: ...

    def array(self, key: str, shape: tuple[int, ...], default: Any = _REQUIRED) -> object:
        """Finite numbers of the given shape (booleans and strings refused)."""
        value = self.get(key, default)
        if key not in self.data:
            return value
        if not _all_numbers(value):
            raise self.error(key, f"expected numbers of shape {shape}")
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as e:
            raise self.error(key, f"expected numbers of shape {shape}") from e
        if arr.shape != shape:
            raise self.error(key, f"expected shape {shape}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise self.error(key, "expected finite numbers")
        return arr

    @overload
    def strings(self, key: str, *, what: str = "strings") -> tuple[str, ...]: ...
    @overload
    def strings(self, key: str, default: Iterable[str], what: str = "strings") -> tuple[str, ...]: ...

    def strings(self, key: str, default: Any = _REQUIRED, what: str = "strings") -> tuple[str, ...]:
        """A list of non-empty strings."""
        value = self.get(key, default)
        if key not in self.data:
            return tuple(value)
        if not isinstance(value, list) or not all(isinstance(e, str) and e.strip() for e in value):
            raise self.error(key, f"expected a list of {what}, got {value!r}")
        return tuple(value)


def _all_numbers(value: Any) -> bool:
    if isinstance(value, (list, tuple)):
        return all(_all_numbers(v) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _span(lo: float | None, hi: float | None, lo_open: bool = False) -> str:
    if lo is not None and hi is not None:
        return f" in {'(' if lo_open else '['}{lo:g}, {hi:g}]"
    if lo is not None:
        return f" {'>' if lo_open else '>='} {lo:g}"
    if hi is not None:
        return f" <= {hi:g}"
    return ""
