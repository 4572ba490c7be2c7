"""bpsflow.files: one JSON conversion everywhere, and writes that never leave half a file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bpsflow.files import jsonable, write_csv, write_json, write_parquet, write_text_atomic


def test_json_converts_numpy_pandas_paths_and_non_finite_floats(tmp_path):
    data = {"float": np.float64(1.5), "int": np.int64(3), "bool": np.bool_(True),
            "array": np.array([1.0, np.nan, np.inf]), "when": pd.Timestamp("2025-07-05 01:00"),
            "path": Path("/x/y"), "nan": float("nan"), "ninf": -np.inf, "nat": pd.NaT,
            "tuple": (1, 2), 7: "key made text"}
    path = write_json(tmp_path / "out.json", data)
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text and text.endswith("}\n")
    assert json.loads(text) == {
        "float": 1.5, "int": 3, "bool": True, "array": [1.0, None, None],
        "when": "2025-07-05 01:00:00", "path": "/x/y", "nan": None, "ninf": None, "nat": None,
        "tuple": [1, 2], "7": "key made text"}
    assert isinstance(jsonable(np.int64(3)), int)


def test_json_refuses_unknown_objects_and_keeps_the_old_file(tmp_path):
    path = write_json(tmp_path / "out.json", {"a": 1})
    with pytest.raises(TypeError, match="not JSON serialisable: object"):
        write_json(path, {"a": object()})
    assert json.loads(path.read_text()) == {"a": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]   # no temporary left


def test_atomic_writers_leave_no_temporary_and_round_trip(tmp_path):
    frame = pd.DataFrame({"a": [1.0, 2.5], "b": ["x", "y"]})
    write_csv(frame, tmp_path / "f.csv", index=False, float_format="%.6g")
    write_parquet(frame, tmp_path / "f.parquet", index=False)
    write_text_atomic(tmp_path / "f.txt", "°C\n")
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "f.csv"), frame)
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "f.parquet"), frame)
    assert (tmp_path / "f.txt").read_text(encoding="utf-8") == "°C\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.csv", "f.parquet", "f.txt"]

    def failing(*_args, **_kwargs):
        raise RuntimeError("disk full")

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(pd.DataFrame, "to_csv", failing)
        with pytest.raises(RuntimeError):
            write_csv(frame, tmp_path / "f.csv")
    assert pd.read_csv(tmp_path / "f.csv").equals(frame)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.csv", "f.parquet", "f.txt"]
