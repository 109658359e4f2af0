"""Every number of a model file is checked after YAML/JSON conversion (issue 30, safety): PyYAML reads a plain
``nan``, ``inf`` or ``1e308`` as text, which numpy then converted to a float, so a model with a NaN base link
loaded and predicted NaN poses. Also: a billion-laughs file, a 2-million-entry list and a huge file are refused in
bounded time, naming the key (or the size)."""

from __future__ import annotations

import json
import re
import time

import numpy as np
import pytest
import yaml

from calibration.errors import DataError, ModelFileError
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.models import ConstantModel, load_model, save_model
from calibration.models.checks import _leaves
from calibration.models.pi import PhysicsInformedModel
from calibration.physics.extended import ExtendedKinematics
from cell_config import load_cell

#: What each numeric leaf is replaced by: a float NaN/inf (JSON writes the literal), text YAML reads as a string
#: numpy converts, a finite number no physical quantity reaches, and a huge integer.
BAD = {"nan": float("nan"), "inf": float("inf"), "-inf": -float("inf"), "text nan": "nan", "text inf": "inf",
       "text 1e308": "1e308", "1e308": 1e308, "huge": 1e300, "huge int": 10**400}


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """A constant and a pi model of R1, saved as YAML; their numeric leaves."""
    root = tmp_path_factory.mktemp("numbers")
    nominal = load_cell().robot("R1").model()
    par = MinimalParameterisation(nominal, fit_tool=True)
    kin = ExtendedKinematics(par)
    theta = np.random.default_rng(3).normal(size=kin.size) * kin.scale() * 0.5
    out = {}
    for name, model in (("constant", ConstantModel("R1", "nls1", par.model(theta[:par.size]), 27, {})),
                        ("pi", PhysicsInformedModel("R1", "pi", kin, theta, kin.size))):
        save_model(model, root / f"{name}.yaml")
        data = yaml.safe_load((root / f"{name}.yaml").read_text())
        keys = [k for k, v in _leaves(data, "") if isinstance(v, (int, float)) and not isinstance(v, bool)]
        out[name] = (data, keys)
    return root, out


def _set(data, key, value):
    """Replace the leaf at a dotted key (``geometry.P[0][0]``)."""
    parts = re.findall(r"[^.\[\]]+|\[\d+\]", key)
    node = data
    for p in parts[:-1]:
        node = node[int(p[1:-1])] if p.startswith("[") else node[p]
    last = parts[-1]
    if last.startswith("["):
        node[int(last[1:-1])] = value
    else:
        node[last] = value


@pytest.mark.parametrize("kind", ["constant", "pi"])
def test_every_numeric_leaf_replaced_by_a_bad_number_is_refused_naming_its_key(saved, tmp_path, kind):
    root, models = saved
    data, keys = models[kind]
    if kind == "pi":  # its 77 parameters and their references: a seeded sample besides the geometry it shares
        rng = np.random.default_rng(0)
        keys = [k for k in keys if "P[" in k or "p_" in k] + list(rng.choice(keys, 20, replace=False))
    assert "geometry.P[0][0]" in keys or "nominal.P[0][0]" in keys, keys[:5]
    bad = BAD if kind == "constant" else {k: BAD[k] for k in ("nan", "text nan", "text 1e308", "huge int")}
    for key in keys:
        for label, value in bad.items():
            d = json.loads(json.dumps(data))
            _set(d, key, value)
            # float NaN and inf as JSON writes them (NaN, Infinity); text as YAML reads it; the rest either way
            path = tmp_path / ("m.yaml" if label.startswith("text") or label == "1e308" else "m.json")
            path.write_text(json.dumps(d) if path.suffix == ".json" else yaml.safe_dump(d))
            with pytest.raises(ModelFileError) as e:
                load_model(path)
            assert e.value.key == key, (key, label, str(e.value))
            assert len(str(e.value).splitlines()) == 1


def test_plain_yaml_nan_in_the_base_link_and_the_tool_is_refused(saved, tmp_path):
    """The reliability pass's files: ``nan``, ``inf``, ``1e308`` typed into the YAML by hand, base and tool."""
    root, _ = saved
    text = (root / "constant.yaml").read_text()
    first_row = re.search(r"  P:\n  - \[([^\]]*)\]", text)
    tool = re.search(r"  p_flange_tool: \[([^\]]*)\]", text) or re.search(r"  p_flange_tool:\n  - ([^\n]*)", text)
    assert first_row and tool
    for word in ("nan", "inf", "1e308", ".nan", "NaN"):
        base = text.replace(first_row.group(0), f"  P:\n  - [{word}, 0.0, 0.0]", 1)
        (tmp_path / "b.yaml").write_text(base)
        with pytest.raises(ModelFileError, match=r"geometry\.P\[0\]\[0\]: expected a"):
            load_model(tmp_path / "b.yaml")
        tooled = text.replace(tool.group(1), f"{word}, " + tool.group(1).split(",", 1)[1].strip(), 1)
        (tmp_path / "t.yaml").write_text(tooled)
        with pytest.raises(ModelFileError, match=r"geometry\.p_flange_tool(\[0\])?: expected a"):
            load_model(tmp_path / "t.yaml")


def test_a_rotation_with_nan_is_refused(saved, tmp_path):
    root, models = saved
    data = json.loads(json.dumps(models["constant"][0]))
    data["geometry"]["R_flange"][0][0] = float("nan")
    path = tmp_path / "m.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ModelFileError, match="geometry.R_flange"):
        load_model(path)
    from calibration.models.checks import _check_rotation  # the rotation check alone, NaN-proof

    with pytest.raises(ModelFileError, match="rotation"):
        _check_rotation("m", "R_x", [[np.nan, 0, 0], [0, 1, 0], [0, 0, 1]])


def test_a_billion_laughs_model_file_is_refused_at_once(saved, tmp_path):
    root, _ = saved
    laughs = ["a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    laughs += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 10)]
    text = (root / "constant.yaml").read_text() + "extra:\n" + "".join(f"  {line}\n" for line in laughs)
    path = tmp_path / "laughs.yaml"
    path.write_text(text)
    t0 = time.perf_counter()
    with pytest.raises(ModelFileError, match=r"extra\.a1\[0\]: refers back to a block used elsewhere \(a YAML alias"):
        load_model(path)
    assert time.perf_counter() - t0 < 2.0


def test_a_two_million_entry_list_is_refused_naming_its_key(saved, tmp_path):
    from calibration.models.checks import MAX_LIST_LENGTH

    root, models = saved
    data = json.loads(json.dumps(models["constant"][0]))
    data["geometry"]["P"][0] = [0.0] * 2_000_000
    path = tmp_path / "long.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ModelFileError, match=rf"geometry\.P\[0\]: a list of 2000000 entries; .* {MAX_LIST_LENGTH}"):
        load_model(path)


def test_a_huge_file_and_a_fifo_are_refused_without_reading_them_whole(tmp_path, monkeypatch):
    import os

    import calibration.models.files as files

    monkeypatch.setattr(files, "MAX_MODEL_FILE_BYTES", 1000)
    big = tmp_path / "big.yaml"
    big.write_text("a: " + "1" * 2000)
    with pytest.raises(DataError, match="MiB limit"):
        load_model(big)
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    with pytest.raises(DataError, match="not a regular file"):
        load_model(fifo)
