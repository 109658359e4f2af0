"""Model files: write a model as YAML or JSON (:func:`save_model`) and read one back with its checks
(:func:`load_model`). A file stores the schema and the kind, never a module path."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from calibration.data.files import atomic_write_text, read_input_text
from calibration.data.yamlio import safe_load
from calibration.errors import DataError, ModelError, ModelFileError, parse_error_text
from calibration.kinematics.poe import PoeModel
from calibration.models.base import READABLE_SCHEMAS, KinematicModel
from calibration.models.checks import (
    MAX_MODEL_FILE_BYTES,
    MAX_POSITION_MM,
    check_model_data,
    check_model_for,
    check_model_numbers,
    check_model_structure,
)
from calibration.models.registry import model_class


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
        OutputError: the path is refused or the write failed (see :func:`calibration.data.files.atomic_open`).
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
    """The decoded model file: a regular file of at most :data:`~calibration.models.checks.MAX_MODEL_FILE_BYTES`
    (a FIFO or a device would block or never end), whose structure can be walked (no aliases, no list beyond
    :data:`~calibration.models.checks.MAX_LIST_LENGTH`)."""
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
            :func:`calibration.models.checks.check_model_for`).

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
