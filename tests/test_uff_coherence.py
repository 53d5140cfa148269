"""Coherence in UFF files from other programs: ordinary (function type 6) or multiple (26),
per pair or per output (ssid.exchange.uff_coherence; rules in docs/exchange.md)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import chain_frf
from conftest import read_uff_with_warnings as read

from ssid.exchange._uffio import write_datasets
from ssid.exchange.uff import frf_datasets

pytest.importorskip("pyuff")

# Coherence is written as E20.11 in ASCII 58 (12 significant digits).
ASCII_RTOL = 1e-11


def uff_with_coherence(path, frf, cohs):
    """Write ``frf``'s FRFs as ASCII 58 followed by the coherence functions ``cohs``, each a
    dict with ``rsp``, ``ref`` (node, direction; node 0 for none), ``value`` (a constant),
    ``type`` (6 or 26) and optionally ``id1``. pyuff writes function type 6 only, so the
    record 6 of each type-26 function is edited afterwards."""
    datasets = [d for d in frf_datasets(str(path), frf) if d.get("func_type") != 6]
    marks = {}
    template = next(d for d in frf_datasets(str(path), _with_coherence(frf))
                    if d.get("func_type") == 6)
    for k, c in enumerate(cohs):
        d = dict(template, rsp_node=c["rsp"][0], rsp_dir=c["rsp"][1], ref_node=c["ref"][0],
                 ref_dir=c["ref"][1], id1=c.get("id1", "Coherence"), func_id=900000 + k,
                 x=frf.freq_hz.copy(), data=np.full(frf.n_freq, c["value"]))
        datasets.append(d)
        marks[900000 + k] = c["type"]
    write_datasets(path, datasets)
    text = path.read_bytes()
    for func_id, ftype in marks.items():
        old = f"{6:5d}{func_id:10d}".encode()
        assert text.count(old) == 1
        text = text.replace(old, f"{ftype:5d}{func_id:10d}".encode())
    path.write_bytes(text)
    return path


def _with_coherence(frf):
    out = chain_frf(n_freq=frf.n_freq)
    out.coherence = np.ones(out.H.shape)
    return out


NODES = [(1, 3), (2, 3), (3, 3)]  # chain_frf: outputs 1+Z, 2+Z, 3+Z; inputs 1+Z, 3+Z


def test_ordinary_coherence_with_several_inputs_is_left_out_with_a_warning(tmp_path):
    """An analyser's ordinary coherence per pair (type 6), two inputs: it was stored as the
    multiple coherence (0.5 where the truth is 1), and the noise weights trusted it (QA)."""
    frf = chain_frf(n_freq=8)
    cohs = [{"rsp": n, "ref": r, "value": 0.5, "type": 6} for r in [(1, 3), (3, 3)] for n in NODES]
    back, found = read(uff_with_coherence(tmp_path / "ord.uff", frf, cohs))
    assert back.coherence is None
    np.testing.assert_allclose(back.H, frf.H, rtol=1e-11)
    assert len(found) == 1 and "6 ordinary coherence function(s)" in found[0]
    assert "with 2 inputs" in found[0] and "multiple coherence" in found[0]


def test_ordinary_coherence_with_one_input_is_read(tmp_path):
    frf = chain_frf(inputs=["1+Z"], n_freq=8)
    cohs = [{"rsp": n, "ref": (1, 3), "value": 0.5 + 0.1 * i, "type": 6} for i, n in enumerate(NODES)]
    back, found = read(uff_with_coherence(tmp_path / "one.uff", frf, cohs))
    assert found == []
    np.testing.assert_allclose(back.coherence[0, :, 0], [0.5, 0.6, 0.7], rtol=ASCII_RTOL)


def test_our_own_multiple_coherence_written_as_type_6_stays_multiple(tmp_path):
    """ssidlab writes multiple coherence as type 6 with ID line 1 saying so: still read."""
    frf = chain_frf(n_freq=8)
    cohs = [{"rsp": n, "ref": r, "value": 0.9, "type": 6, "id1": "x/y multiple coherence"}
            for r in [(1, 3), (3, 3)] for n in NODES]
    back, found = read(uff_with_coherence(tmp_path / "own.uff", frf, cohs))
    assert found == []
    np.testing.assert_allclose(back.coherence, 0.9, rtol=ASCII_RTOL)


def test_multiple_coherence_wins_over_ordinary_for_the_same_pair(tmp_path):
    """Ordinary (6) and multiple (26) coherence of one pair were refused as 'both the
    coherence 1+Z/1+Z' (QA); the multiple one is the FRF file's."""
    for inputs, refs in ((["1+Z"], [(1, 3)]), (None, [(1, 3), (3, 3)])):
        frf = chain_frf(inputs=inputs, n_freq=8)
        cohs = [{"rsp": n, "ref": r, "value": 0.5, "type": 6} for r in refs for n in NODES]
        cohs += [{"rsp": n, "ref": r, "value": 0.9, "type": 26} for r in refs for n in NODES]
        back, found = read(uff_with_coherence(tmp_path / "both.uff", frf, cohs))
        assert found == []
        np.testing.assert_allclose(back.coherence, 0.9, rtol=ASCII_RTOL)


@pytest.mark.parametrize("ref", [(0, 0), (1, 3)], ids=["reference node 0", "one reference"])
@pytest.mark.parametrize("with_ordinary", [False, True])
def test_one_multiple_coherence_per_output_is_that_outputs_for_every_input(tmp_path, ref,
                                                                           with_ordinary):
    """A multiple coherence belongs to the output, not to one input: written with reference
    node 0 it was refused ('reference (input) node number 0 is outside ...'), written against
    one of two inputs it was dropped for not covering the other (QA)."""
    frf = chain_frf(n_freq=8)
    cohs = [{"rsp": n, "ref": ref, "value": 0.6 + 0.1 * i, "type": 26} for i, n in enumerate(NODES)]
    if with_ordinary:
        cohs = [{"rsp": n, "ref": r, "value": 0.5, "type": 6} for r in [(1, 3), (3, 3)]
                for n in NODES] + cohs
    back, found = read(uff_with_coherence(tmp_path / "out.uff", frf, cohs))
    assert found == []
    np.testing.assert_allclose(back.coherence, np.broadcast_to([[0.6], [0.7], [0.8]],
                                                               back.H.shape), rtol=ASCII_RTOL)


def test_a_coherence_that_cannot_be_placed_is_left_out_and_the_frfs_read(tmp_path):
    """A coherence with response node 0 was a refusal naming a 'response node number' only;
    it is a coherence, which the FRFs do not need: left out with a warning saying so."""
    frf = chain_frf(inputs=["1+Z"], n_freq=8)
    cohs = [{"rsp": n, "ref": (1, 3), "value": 0.9, "type": 6} for n in NODES]
    cohs.append({"rsp": (0, 3), "ref": (1, 3), "value": 0.9, "type": 6})
    back, found = read(uff_with_coherence(tmp_path / "node0.uff", frf, cohs))
    assert len(found) == 1 and "dataset 8 (58) is a coherence function that cannot be placed" in found[0]
    assert "response node number 0" in found[0] and "FRFs are read without it" in found[0]
    np.testing.assert_allclose(back.coherence, 0.9, rtol=ASCII_RTOL)  # the others cover it


def test_two_multiple_coherences_of_one_pair_leave_the_coherence_out(tmp_path):
    frf = chain_frf(inputs=["1+Z"], n_freq=8)
    cohs = [{"rsp": n, "ref": (1, 3), "value": 0.9, "type": 26} for n in NODES]
    cohs.append({"rsp": (2, 3), "ref": (1, 3), "value": 0.8, "type": 26})
    back, found = read(uff_with_coherence(tmp_path / "dup.uff", frf, cohs))
    assert back.coherence is None and len(found) == 1
    assert "are both the multiple coherence of 2+Z/1+Z" in found[0]
    assert "the FRFs were read without it" in found[0]
    np.testing.assert_allclose(back.H, frf.H, rtol=1e-11)
