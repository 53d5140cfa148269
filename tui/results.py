"""The Results tab's content, computed from a finished run file; and its exports.

Everything here calls ``ssid`` (identification, correlation, discrepancy, exchange, plots) or
``daq.simlab`` (the nominal model of a simulated setup); nothing is computed here. Which
analysis model the identified model is held against:

* a model file given on the Setup tab (``ssid.matrix_io.read_analysis_model``: model HDF5,
  MAT, OP4) - the structure as tested: MAC and the discrepancy workflow both use it;
* otherwise, for the simulated lab, its nominal model (every hidden ``[[sim.effects]]``
  removed): the structure alone for MAC (SSID with reactions identifies the free
  substructure), the structure on its stand for the discrepancy workflow (the measured FRFs
  are on the stand) - as in ``ssidlab demo``;
* otherwise none: modes only, and the Results tab says how to give one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .session import naming, one_line, printable

__all__ = ["ModeRow", "RunResults", "analyse_run", "export_results", "model_refusal"]


@dataclass
class ModeRow:
    mode: int
    freq_hz: float
    damping_ratio: float
    mpc: float
    in_band: bool = True  # within the band of lines used for the fit


@dataclass
class RunResults:
    """What the Results tab shows, and what the exports write."""

    path: Path
    frf: object  # ssid.frf.FRFData
    result: object  # ssid.result.SSIDResult
    modes: list[ModeRow]
    description: str
    model_source: str = ""  # which analysis model, in words ("" = none)
    pairs: list[dict] = field(default_factory=list)  # MAC-paired modes (ssid.correlate_models)
    discrepancy: dict | None = None  # DiscrepancyResult.to_json_dict()
    notes: list[str] = field(default_factory=list)  # what could not be done, one line each
    predicted: np.ndarray | None = None  # identified model's FRF under the test's loads (n_freq, n_out, n_in)
    updated: np.ndarray | None = None  # the discrepancy-updated model's FRF, same shape
    updated_model: object | None = None  # ssid.io.Model: the analysis model with the effect added

    def discrepancy_text(self) -> str:
        d = self.discrepancy
        if d is None:
            # The workflow's notes carry their own "discrepancy workflow: " already.
            return "; ".join(n for n in self.notes if "discrepancy" in n) or "discrepancy workflow: no analysis model"
        if d["effect"] == "none":
            # The workflow's own words: "agrees within noise" only when the gap is at the noise.
            return (f"discrepancy workflow ({self.model_source}): no effect named: {d['residual']['text']} "
                    f"(gap {d['gap_before']:.3g})")
        params = ", ".join(f"{k} {v:.4g}" for k, v in d["parameters"].items())
        return (f"discrepancy workflow ({self.model_source}): {d['effect']} at {', '.join(d['dofs'])} "
                f"({params}); gap {d['gap_before']:.3g} -> {d['gap_after']:.3g} (noise-normalised RMS)")


def model_refusal(model_path: str, setup) -> str | None:
    """Why the model file cannot serve a run of ``setup``, as one line naming the file, or None.

    Read as the Results tab will read it (``ssid.matrix_io.read_analysis_model``), so that a
    file which is no model, a model that is not a physical structure, or a model without the
    setup's response DOFs (MAC and the discrepancy workflow both need every one), is refused
    before the run, not after it. Physical is what ``ssidlab discrepancy`` takes
    (``ssid.discrepancy.check_model``): M positive semi-definite and not zero, K and C positive
    semi-definite, and M positive definite when there is no C. Massless DOFs with a C (a
    lumped model's rotations) pass: the discrepancy workflow takes them, and only the MAC
    (which needs normal modes) then says it cannot.

    Parameters
    ----------
    model_path : str
        The model file (model HDF5, MAT, OP4); "" for none, which is always fine.
    setup : daq.setup.TestSetup
        The loaded setup; its ``outputs`` are the response DOFs of the run's FRFs.
    """
    if not model_path:
        return None
    from ssid.discrepancy import check_model
    from ssid.matrix_io import read_analysis_model

    try:
        model = read_analysis_model(model_path)
        # A negative or absent mass is not found by reading (the file's layout is fine); the
        # run would end with notes in place of the MAC and the discrepancy finding.
        check_model(model)
    except Exception as exc:  # noqa: BLE001 -- whatever the reader says is the one line
        return naming(model_path, exc)
    missing = [d for d in setup.outputs if d not in set(model.dofs)]
    if not missing:
        return None
    n = len(setup.outputs)
    which = f"has none of the setup's {n}" if len(missing) == n else f"lacks {len(missing)} of the setup's {n}"
    return (f"{printable(model_path)}: the model {which} response DOFs ({missing[0]!r} first); "
            f"MAC and the discrepancy workflow need them all")


def _models(setup, sim: bool, model_path: str | None):
    """(model for MAC, model for the discrepancy workflow, words) or (None, None, why not)."""
    if model_path:
        from ssid.matrix_io import read_analysis_model

        m = read_analysis_model(model_path)
        return m, m, Path(model_path).name
    if sim and setup is not None:
        from daq.simlab import nominal_model

        return (nominal_model(setup, mounted=False), nominal_model(setup, mounted=True),
                "nominal model of the simulated lab")
    return None, None, "no analysis model: give a model file on the Setup tab"


def analyse_run(path: str | Path, setup=None, *, sim: bool = False, model_path: str | None = None) -> RunResults:
    """Identify M, C, K from a finished run file; correlate and look for the discrepancy.

    Identification failing raises (the caller shows one line); correlation or discrepancy
    failing leaves a note instead, since the identified modes are still worth showing.
    """
    from ssid.frf import accelerance_under_test_loads
    from ssid.identify import identify_mck
    from ssid.io import read_measured_frf

    path = Path(path)
    frf = read_measured_frf(path)
    res = identify_mck(frf)
    lo, hi = res.band_hz
    rows = [ModeRow(i + 1, float(f), float(z), float(m), bool(lo <= f <= hi))
            for i, (f, z, m) in enumerate(zip(res.natural_freq_hz, res.damping_ratio, res.mpc, strict=False))]
    desc = (f"{path.name}: {frf.n_freq} lines, {frf.n_out} outputs x {frf.n_in} inputs; "
            f"{len(rows)} modes ({res.solver}, {lo:.4g}-{hi:.4g} Hz)")
    out = RunResults(path, frf, res, rows, desc)
    # Of identify's warnings, the one that questions the data themselves; the others (a
    # blanked column, a real root) are in the run log's terms already or too fine for 24 rows.
    out.notes.extend(f"warning: {w}" for w in res.warnings if w.startswith("reciprocity"))
    out.predicted = accelerance_under_test_loads(res.M, res.C, res.K, list(res.dofs), frf)
    try:
        mac_model, disc_model, words = _models(setup, sim, model_path)
    except Exception as exc:  # noqa: BLE001 -- a bad model file is a note, not a lost result
        out.notes.append(f"analysis model: {one_line(exc)}")
        return out
    out.model_source = words if mac_model is not None else ""
    if mac_model is None:
        out.notes.append(words)
        return out
    try:
        from ssid.correlate_models import correlate_models

        out.pairs = list(correlate_models(res.to_model(), mac_model).summary["paired_modes"])
    except Exception as exc:  # noqa: BLE001
        out.notes.append(f"MAC: {one_line(exc)}")
    try:
        from ssid.discrepancy import find_discrepancy

        # The simulated lab's model includes its stand, whose reactions are internal forces;
        # an engineer's model may be the substructure alone, which the measured reactions
        # load as they loaded the test article: the data decide (ssid.reaction_loads).
        disc = find_discrepancy(disc_model, frf, reactions="auto" if model_path else "ignore")
        out.discrepancy = disc.to_json_dict()
        out.updated_model = disc.updated_model
        out.updated = disc.arrays["H_updated"]  # on every line: the workflow was given the whole band
        if disc.info["calibration"]["flagged"]:
            out.notes.append(f"warning: {disc.info['calibration']['text']}")
    except Exception as exc:  # noqa: BLE001
        out.notes.append(f"discrepancy workflow: {one_line(exc)}")
    return out


def export_results(results: RunResults, kind: str, out_i: int = 0, in_j: int = 0) -> list[Path]:
    """Write the results next to the run file; the paths written.

    ``hdf5``: the identified model (``<run>_ssid_model.h5``, model-file contract) and, with a
    discrepancy finding, the updated analysis model (``<run>_updated_model.h5``); ``uff``:
    the measured FRFs as UFF 58 (``<run>.uff``); ``png``: FRF ``(out_i, in_j)`` measured vs
    identified (and updated) model (``<run>_frf_<out>_<in>.png``).
    """
    from ssid.io import write_model

    base = results.path.with_suffix("")
    res = results.result
    written: list[Path] = []
    if kind == "hdf5":
        p = Path(f"{base}_ssid_model.h5")
        write_model(p, res.to_model())
        written.append(p)
        if results.updated_model is not None:
            p = Path(f"{base}_updated_model.h5")
            write_model(p, results.updated_model)
            written.append(p)
    elif kind == "uff":
        from ssid.exchange import write_uff_frf

        p = Path(f"{base}.uff")
        write_uff_frf(str(p), results.frf)
        written.append(p)
    elif kind == "png":
        from ssid.plots_correlation import plot_frf_overlay

        frf = results.frf
        o, i = frf.outputs[out_i], frf.inputs[in_j]
        safe = "".join(ch if ch.isalnum() else "_" for ch in f"{o}_{i}")
        p = Path(f"{base}_frf_{safe}.png")
        plot_frf_overlay(frf.freq_hz, frf.H[:, out_i, in_j], results.predicted[:, out_i, in_j], p,
                         title=f"{o} / {i}: measured vs SSID model under the test's loads",
                         labels=("measured", "SSID model"), valid=frf.valid_mask()[:, out_i, in_j])
        written.append(p)
    else:
        raise ValueError(f"unknown export kind {kind!r} (hdf5, uff, png)")
    return written
