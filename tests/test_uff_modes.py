"""UFF exchange of mode shapes (dataset 55) and geometry (2411, 15)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import chain_frf, chain_model

from ssid.errors import InputError
from ssid.exchange import (
    UFFModes,
    modes_from_model,
    modes_from_result,
    read_uff_geometry,
    read_uff_modes,
    write_uff_frf,
    write_uff_geometry,
    write_uff_modes,
)

pytest.importorskip("pyuff")


def test_complex_modes_round_trip(tmp_path):
    m = chain_model()
    modes = modes_from_model(m.M, m.C, m.K, m.dofs)
    geometry = {1: (0.0, 0.0, 0.0), 2: (0.1, 0.0, 0.0), 3: (0.2, 0.0, 0.0)}
    write_uff_modes(tmp_path / "modes.uff", modes, geometry=geometry)
    back = read_uff_modes(tmp_path / "modes.uff", dofs=m.dofs)
    # Dataset 55 is E13.5: 6 significant digits (shapes are scaled to a largest entry of 1).
    np.testing.assert_allclose(back.natural_freq_hz, modes.natural_freq_hz, rtol=1e-5)
    np.testing.assert_allclose(back.damping_ratio, modes.damping_ratio, rtol=2e-5)
    np.testing.assert_allclose(back.mode_shapes, modes.mode_shapes, atol=1e-5)
    assert read_uff_geometry(tmp_path / "modes.uff")[3][0] == 0.2
    # Without a selection every node component comes back, unmeasured ones as 0.
    every = read_uff_modes(tmp_path / "modes.uff")
    assert every.dofs[:3] == ["1+X", "1+Y", "1+Z"]


def test_modes_from_an_identification_result_json(tmp_path):
    m = chain_model()
    modes = modes_from_model(m.M, m.C, m.K, m.dofs)
    result = {"natural_freq_hz": list(modes.natural_freq_hz) + [None],
              "damping_ratio": list(modes.damping_ratio) + [None],
              "dofs": m.dofs,
              "mode_shapes": {"dofs": m.dofs,
                              "real": np.c_[modes.mode_shapes.real, np.zeros(3)].tolist(),
                              "imag": np.c_[modes.mode_shapes.imag, np.zeros(3)].tolist()}}
    got = modes_from_result(result)
    assert got.natural_freq_hz.size == 3  # the undetermined mode is left out
    write_uff_modes(tmp_path / "r.uff", got)
    back = read_uff_modes(tmp_path / "r.uff", dofs=["3+Z", "1-Z"])
    np.testing.assert_allclose(back.mode_shapes[1], -modes.mode_shapes[0], atol=1e-5)


def test_real_modes_with_rotations_and_the_limits_of_complex_ones(tmp_path):
    m = chain_model()
    dofs = ["1+Z", "1+RY", "2-RX"]
    modes = modes_from_model(m.M, None, m.K, dofs)
    write_uff_modes(tmp_path / "real.uff", modes)
    back = read_uff_modes(tmp_path / "real.uff", dofs=dofs)
    assert back.mode_shapes.dtype.kind == "f"
    np.testing.assert_allclose(back.mode_shapes, modes.mode_shapes,
                               atol=5e-6 * np.abs(modes.mode_shapes).max())
    np.testing.assert_allclose(back.damping_ratio, 0.0)
    complex_modes = modes_from_model(m.M, m.C, m.K, dofs)
    with pytest.raises(InputError, match="rotation"):
        write_uff_modes(tmp_path / "c.uff", complex_modes)
    with pytest.raises(InputError, match="same node component"):
        write_uff_modes(tmp_path / "c.uff", UFFModes(modes.natural_freq_hz, modes.damping_ratio,
                                                     modes.mode_shapes, ["1+Z", "1-Z", "2+Z"]))
    with pytest.raises(InputError, match="no value for DOF"):
        read_uff_modes(tmp_path / "real.uff", dofs=["9+Z"])
    with pytest.raises(InputError, match="no mode shapes"):
        read_uff_modes(_frf_only(tmp_path))


def test_geometry_round_trip_and_dataset_15(tmp_path):
    geometry = {7: (1.0, -1.0, 0.5), 3: (0.0, 2.0, -1.25)}
    write_uff_geometry(tmp_path / "g.uff", geometry)
    back = read_uff_geometry(tmp_path / "g.uff")
    assert sorted(back) == [3, 7]
    np.testing.assert_array_equal(back[7], geometry[7])
    # Dataset 15 (single precision, older programs).
    text = ("    -1\n    15\n"
            f"{5:10d}{0:10d}{0:10d}{8:10d}{1.5:13.5E}{-2.0:13.5E}{0.25:13.5E}\n"
            "    -1\n")
    (tmp_path / "g15.unv").write_text(text)
    np.testing.assert_array_equal(read_uff_geometry(tmp_path / "g15.unv")[5], [1.5, -2.0, 0.25])
    with pytest.raises(InputError, match="no node coordinates"):
        read_uff_geometry(_frf_only(tmp_path))


def _frf_only(tmp_path: Path) -> Path:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_uff_frf(tmp_path / "frf_only.uff", chain_frf(n_freq=4))
    return tmp_path / "frf_only.uff"
