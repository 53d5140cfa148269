"""Helpers shared by the subcommands: strict JSON and output-path checks."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import numpy as np
import pytest

from ssid.errors import InputError
from ssid.jsonutil import to_jsonable
from ssidlab.argtypes import check_output_paths, write_chart


def test_to_jsonable_gives_strict_json():
    obj = {"a": np.array([1.0, np.nan, np.inf]), "b": np.int64(3), "c": np.bool_(True),
           "d": (np.float32(0.5), Path("x/y")), 4: [np.float64(-np.inf)]}
    out = to_jsonable(obj)
    assert json.loads(json.dumps(out, allow_nan=False)) == {
        "a": [1.0, None, None], "b": 3, "c": True, "d": [0.5, "x/y"], "4": [None]}


def test_check_output_paths(tmp_path):
    src = tmp_path / "in.h5"
    src.write_text("x")
    check_output_paths([str(src)], [str(tmp_path / "a.h5"), None, str(tmp_path / "b.json")])
    with pytest.raises(InputError, match="overwrite the input file"):
        check_output_paths([str(src)], [str(src)])
    with pytest.raises(InputError, match="overwrite an input file"):
        check_output_paths([str(src), str(tmp_path / "other.h5")], [str(src)])
    with pytest.raises(InputError, match="two different outputs"):
        check_output_paths([str(src)], [str(tmp_path / "a"), str(tmp_path / "a")])
    with pytest.raises(InputError, match="is a directory"):
        check_output_paths([str(src)], [str(tmp_path)])
    with pytest.raises(InputError, match="does not exist"):
        check_output_paths([str(src)], [str(tmp_path / "no" / "a.h5")])
    os.link(src, tmp_path / "hard.h5")  # another name of the same file
    with pytest.raises(InputError, match="overwrite the input file"):
        check_output_paths([str(src)], [str(tmp_path / "hard.h5")])


def test_write_chart_passes_the_result_and_makes_a_file_error_one_line(tmp_path):
    assert write_chart(str(tmp_path / "a.png"), lambda path: [path]) == [str(tmp_path / "a.png")]

    def disk_full(path):
        raise OSError(errno.ENOSPC, "No space left on device", path)

    with pytest.raises(InputError) as excinfo:
        write_chart("roots.png", disk_full)
    assert str(excinfo.value) == "roots.png: cannot write the chart (No space left on device)"
