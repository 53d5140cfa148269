"""Model export: MATLAB .mat, Nastran OP4 (pyyeti) and DMIG bulk data, read back independently."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import chain_frf, chain_model

from ssid.errors import InputError
from ssid.export import export_model, export_model_dmig, export_model_mat, export_model_op4
from ssid.io import Model, write_model
from ssid.matrix_io import read_analysis_model
from ssidlab import cli
from ssidlab.cli_export import add_export_model_subcommand

# DMIG numbers have 10 (two-digit exponent) or 11 significant digits.
DMIG_RTOL = 1e-9


def damped_model(dofs: list[str]) -> Model:
    """The chain model with a non-symmetric damping term (C need not be symmetric)."""
    m = chain_model()
    C = m.C.copy()
    C[0, 2] += 0.125
    return Model(M=m.M, K=m.K, C=C, dofs=dofs)


def flipped(A: np.ndarray, dofs: list[str]) -> np.ndarray:
    """A in '+' axes: rows and columns of '-' labels negated."""
    s = np.array([-1.0 if "-" in d else 1.0 for d in dofs])
    return s[:, None] * A * s[None, :]


# ----------------------------------------------------------------------------------------------
# MATLAB
# ----------------------------------------------------------------------------------------------


def test_mat_round_trip_keeps_any_labels(tmp_path):
    dofs = ["base x", "tip (accel 2)", "3+Z"]
    model = damped_model(dofs)
    export_model_mat(tmp_path / "m.mat", model)
    back = read_analysis_model(tmp_path / "m.mat")
    assert back.dofs == dofs
    for name in "MCK":
        np.testing.assert_array_equal(getattr(back, name), getattr(model, name))
    import scipy.io

    raw = scipy.io.loadmat(tmp_path / "m.mat")
    assert raw["dofs"].dtype == object and raw["dofs"].shape == (3, 1)  # a cellstr column


def test_mat_without_damping_has_no_C(tmp_path):
    m = chain_model()
    export_model_mat(tmp_path / "m.mat", Model(M=m.M, K=m.K, C=None, dofs=m.dofs))
    assert read_analysis_model(tmp_path / "m.mat").C is None


# ----------------------------------------------------------------------------------------------
# OP4
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("binary", [True, False])
def test_op4_round_trip(tmp_path, binary):
    op4 = pytest.importorskip("pyyeti.nastran.op4")
    dofs = ["1+Z", "2-RX", "7"]
    model = damped_model(dofs)
    export_model_op4(tmp_path / "m.op4", model, binary=binary)
    raw = op4.read(str(tmp_path / "m.op4"))
    assert list(raw) == ["maa", "baa", "kaa", "dofs"]  # pyyeti lower-cases names on reading
    np.testing.assert_array_equal(raw["dofs"], [[1, 3], [2, 4], [7, 0]])
    back = read_analysis_model(tmp_path / "m.op4")
    assert back.dofs == ["1+Z", "2+RX", "7"]
    # Binary OP4 holds float64; ASCII 1P,3E23.16 has the 17 digits that round-trip a float64.
    rtol = 0.0
    for name in "MCK":
        np.testing.assert_allclose(getattr(back, name), flipped(getattr(model, name), dofs),
                                   rtol=rtol, atol=0)


def test_op4_needs_grid_component_labels(tmp_path):
    with pytest.raises(InputError, match="'tip'"):
        export_model_op4(tmp_path / "m.op4", damped_model(["1+Z", "tip", "3+Z"]))
    with pytest.raises(InputError, match="same grid component"):
        export_model_op4(tmp_path / "m.op4", damped_model(["1+Z", "1-Z", "3+Z"]))


# ----------------------------------------------------------------------------------------------
# DMIG, checked with an independent minimal parser
# ----------------------------------------------------------------------------------------------


def parse_dmig(text: str) -> dict[str, dict]:
    """Minimal reader of large-field DMIG* cards: {name: {"ifo", "tin", "terms"}}."""
    cards: list[list[str]] = []
    for line in text.splitlines():
        if not line.strip() or line.startswith("$"):
            continue
        fields = [line[8 + 16 * k: 8 + 16 * (k + 1)].strip() for k in range(4)]
        if line.startswith("DMIG*"):
            cards.append(fields)
        else:
            assert line.startswith("*"), line
            cards[-1].extend(fields)
    out: dict[str, dict] = {}
    for card in cards:
        name = card[0]
        if card[1] == "0":  # header: NAME, 0, IFO, TIN, TOUT
            out[name] = {"ifo": int(card[2]), "tin": int(card[3]), "terms": {}}
            continue
        column = (int(card[1]), int(card[2]))
        assert card[3] == ""
        for k in range(4, len(card), 4):
            g, c, a, b = card[k: k + 4]
            assert b == "" and (g, c) != ("", "")
            value = float(a.replace("D", "E"))
            out[name]["terms"][((int(g), int(c)), column)] = value
    return out


def dmig_matrix(entry: dict, order: list[tuple[int, int]]) -> np.ndarray:
    index = {gc: i for i, gc in enumerate(order)}
    A = np.zeros((len(order), len(order)))
    for (row, col), value in entry["terms"].items():
        A[index[row], index[col]] = value
        if entry["ifo"] == 6:
            A[index[col], index[row]] = value
    return A


def test_dmig_round_trip_with_an_independent_parser(tmp_path):
    dofs = ["1+Z", "2-RX", "7"]
    model = damped_model(dofs)
    model.K = model.K * 1.000000123456789  # digits beyond 8 must survive
    export_model_dmig(tmp_path / "m.bdf", model)
    text = (tmp_path / "m.bdf").read_text()
    assert max(len(line) for line in text.splitlines()) <= 80
    cards = parse_dmig(text)
    assert set(cards) == {"MSSID", "BSSID", "KSSID"}
    assert cards["MSSID"]["ifo"] == 6 and cards["KSSID"]["ifo"] == 6
    assert cards["BSSID"]["ifo"] == 1  # C is not symmetric
    assert all(c["tin"] == 2 for c in cards.values())
    order = [(1, 3), (2, 4), (7, 0)]
    # A symmetric DMIG holds only the upper triangle.
    assert all(order.index(r) <= order.index(c) for r, c in cards["KSSID"]["terms"])
    for name, key in (("M", "MSSID"), ("C", "BSSID"), ("K", "KSSID")):
        np.testing.assert_allclose(dmig_matrix(cards[key], order),
                                   flipped(getattr(model, name), dofs), rtol=DMIG_RTOL, atol=0)


def test_dmig_numbers_fit_16_columns(tmp_path):
    m = chain_model()
    M = np.diag([1.234567890123e-123, -9.87654321e150, 3.0])
    export_model_dmig(tmp_path / "m.dmig", Model(M=M, K=m.K, C=None, dofs=m.dofs),
                      names=("MX", "BX", "KX"))
    cards = parse_dmig((tmp_path / "m.dmig").read_text())
    assert "BX" not in cards  # undamped: no damping matrix
    np.testing.assert_allclose(dmig_matrix(cards["MX"], [(1, 3), (2, 3), (3, 3)]), M,
                               rtol=1e-8)


def test_dmig_refuses_bad_names_and_labels(tmp_path):
    model = damped_model(["1+Z", "2+Z", "3+Z"])
    with pytest.raises(InputError, match="matrix name"):
        export_model_dmig(tmp_path / "m.bdf", model, names=("MASS_MATRIX", "B", "K"))
    with pytest.raises(InputError, match="different matrix names"):
        export_model_dmig(tmp_path / "m.bdf", model, names=("M", "M", "K"))
    with pytest.raises(InputError, match="node"):
        export_model_dmig(tmp_path / "m.bdf", damped_model(["1+Z", "2+Z", "x"]))


@pytest.mark.parametrize("dofs, grid", [(["7", "7+X", "2+Z"], "7+X"),
                                        (["7-RY", "2+Z", "7"], "7-RY")])
@pytest.mark.parametrize("name", ["m.dmig", "m.op4"])
def test_one_id_as_scalar_point_and_grid_is_refused(tmp_path, dofs, grid, name):
    """Scalar point 7 and grid 7 in one model were exported (QA, em_spoint_grid.h5); Nastran
    numbers GRID and SPOINT points in one space, so the file could not be used."""
    if name.endswith(".op4"):
        pytest.importorskip("pyyeti")
    with pytest.raises(InputError) as exc:
        export_model(tmp_path / name, damped_model(dofs))
    message = str(exc.value)
    assert f"DOFs '7' (scalar point 7) and '{grid}' (grid 7)" in message
    assert "SPOINT and a GRID" in message and "\n" not in message
    assert not (tmp_path / name).exists()


def test_export_model_picks_the_format_from_the_extension(tmp_path):
    model = damped_model(["1+Z", "2+Z", "3+Z"])
    assert export_model(tmp_path / "a.bdf", model) == "dmig"
    assert export_model(tmp_path / "a.mat", model) == "mat"
    with pytest.raises(InputError, match="extension"):
        export_model(tmp_path / "a.txt", model)


# ----------------------------------------------------------------------------------------------
# ssidlab export-model
# ----------------------------------------------------------------------------------------------


@pytest.fixture
def ssidlab(monkeypatch, capsys):
    _, subcommands = cli._build_parser()
    if "export-model" not in subcommands:
        monkeypatch.setattr(cli, "_SUBCOMMANDS",
                            cli._SUBCOMMANDS + (add_export_model_subcommand,))

    def run(*argv):
        status = cli.main([str(a) for a in argv])
        out, err = capsys.readouterr()
        return status, out, err

    return run


def test_cli_exports_and_reads_back(tmp_path, ssidlab):
    model = damped_model(["1+Z", "2+Z", "3+Z"])
    write_model(tmp_path / "model.h5", model)
    for out in ("m.mat", "m.op4", "m.dmig"):
        status, text, err = ssidlab("export-model", tmp_path / "model.h5", tmp_path / out)
        assert status == 0 and "M, C, K over 3 DOFs" in text, err
    status, _, _ = ssidlab("export-model", tmp_path / "model.h5", tmp_path / "n.txt",
                           "--format", "op4", "--ascii", "--names", "ma,ba,ka")
    assert status == 0
    # An exported model is itself an input (.op4 -> .mat).
    assert ssidlab("export-model", tmp_path / "n.txt", tmp_path / "n.mat")[0] == 2  # no .op4 name
    assert ssidlab("export-model", tmp_path / "m.op4", tmp_path / "n.mat")[0] == 0
    np.testing.assert_array_equal(read_analysis_model(tmp_path / "n.mat").C, model.C)


@pytest.mark.parametrize("args, expected", [
    (("model.h5", "out.xyz"), "extension"),
    (("model.h5", "out.dmig", "--ascii"), "--ascii"),
    (("model.h5", "out.mat", "--names", "A,B,C"), "--names"),
    (("model.h5", "out.dmig", "--names", "A,B"), "three names"),
    (("missing.h5", "out.mat"), "no such file"),
    (("model.h5", "nodir/out.mat"), "does not exist"),
])
def test_cli_bad_input_is_one_line_and_status_2(tmp_path, ssidlab, args, expected):
    write_model(tmp_path / "model.h5", damped_model(["1+Z", "2+Z", "3+Z"]))
    argv = [a if a.startswith("-") or a.isupper() or "," in a else tmp_path / a for a in args]
    status, _, err = ssidlab("export-model", *argv)
    assert status == 2 and err.count("\n") == 1 and expected in err, err


@pytest.mark.parametrize("name", ["out.mat", "out.op4", "out.dmig", "frf.uff", "model.h5"])
def test_a_file_that_cannot_be_created_is_named_as_asked(tmp_path, name):
    """Every writer goes through a temporary file beside the target (``ssid.files``): when
    that cannot be created, the error names the file asked for, not the temporary one (the
    .mat writer said only "Reader needs file name or open file-like object"), and nothing
    is left behind."""
    from ssid.exchange import write_uff_frf
    from ssid.io import write_model

    (tmp_path / "a_file").write_text("not a directory")
    target = tmp_path / "a_file" / name
    model = damped_model(["1+Z", "2+Z", "3+Z"])
    with pytest.raises(OSError) as e:
        if name.endswith(".uff"):
            write_uff_frf(str(target), chain_frf())
        elif name.endswith(".h5"):
            write_model(target, model)
        else:
            export_model(target, model)
    assert str(e.value) == f"{target}: cannot write (Not a directory)"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]
