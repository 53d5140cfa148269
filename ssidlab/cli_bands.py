"""``ssidlab bands``: band processing of a measured FRF file (report section 5.2).

    ssidlab bands FRF.h5 --json RESULT.json [--plot ROOTS.png] [--out MODEL.h5]
                  [--fmin HZ] [--fmax HZ] [--width HZ] [--overlap FRACTION]
                  [--mpc-min MPC] [--repeat-tol FRACTION] [--solver ml|ls|tls|stls]
                  [--scale BP1|BP2|BP3] [--targets FE_MODEL] [--target-modes 1,2,...]
                  [--no-residual-pair] [--no-rigid-body] [--quiet]

Overlapping bands, each through step 1 and the eigenproblem (Eq. 3.12); each root judged by
the report's four criteria (outside its band, negative damping, MPC below ``--mpc-min``, not
repeated in another band within ``--repeat-tol`` of the width that locates it); one root per
mode kept. It prints the modes found, writes every root and its verdict to the JSON file, the
stabilisation-style chart of roots per band to ``--plot`` and, with ``--out``, the n-DOF model
assembled from the n strongest modes with independent shapes as real normal modes, scaled by
``--scale`` (``ssid.modal_model.modal_model_from_bands``). Which n modes that model holds is
the data's choice unless an FE model names the target modes (``--targets``; the report picked
its roots by hand): roots paired with them (MAC >= 0.8 and frequency) are kept first. With
one mode too few, the last pair is fitted above the band to what the found modes leave of the
FRFs (a residual pair, said in a warning; ``--no-residual-pair`` refuses instead). On a
free-free structure whose rigid-body modes lie below the first line, they are fitted to the
mass line of that residual (said in a warning; ``--no-rigid-body`` refuses instead).

Bad input raises :class:`ssid.errors.InputError`; ``ssidlab.cli.main`` prints it as one line
and exits with status 2.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

from ssid.errors import IdentificationError, InputError
from ssidlab.argtypes import (
    chart_file,
    check_output_paths,
    fe_normal_modes,
    frequency_hz,
    open_fraction,
    parse_mode_list,
    positive_number,
    write_chart,
    write_json,
)

__all__ = ["add_bands_subcommand", "run_bands"]

HELP = ("Band processing (report section 5.2): modes found in overlapping bands, the roots "
        "chart, and a modal M, C, K model.")
SOLVERS = ("ml", "ls", "tls", "stls")
SCALES = ("BP1", "BP2", "BP3")


def add_bands_subcommand(sub: Any) -> argparse.ArgumentParser:
    """Add the ``bands`` subparser to ``sub`` (an argparse subparsers action); returns it."""
    p = sub.add_parser("bands", prog="ssidlab bands", help=HELP, description=HELP,
                       allow_abbrev=False)
    p.add_argument("frf", metavar="FRF.h5", help="measured FRFs (ssidlab-frf file, no reactions)")
    p.add_argument("--json", metavar="RESULT.json", required=True,
                   help="bands, every root with its verdict, the modes found (and the model)")
    p.add_argument("--plot", type=chart_file, metavar="ROOTS.png", help="chart of the roots per band (PNG)")
    p.add_argument("--out", metavar="MODEL.h5",
                   help="modal M, C, K over the FRF file's outputs (ssidlab-model file)")
    p.add_argument("--fmin", type=frequency_hz, metavar="HZ", help="lowest frequency line used")
    p.add_argument("--fmax", type=frequency_hz, metavar="HZ", help="highest frequency line used")
    p.add_argument("--width", type=positive_number, metavar="HZ",
                   help="band width (default: 1/12 of the record, at least 24 lines; on "
                        "unevenly spaced lines, e.g. a stepped-sine sweep, bands of that many "
                        "lines instead of one width)")
    p.add_argument("--overlap", type=open_fraction, default=0.5, metavar="FRACTION",
                   help="overlap of neighbouring bands (default 0.5: every line in two bands)")
    p.add_argument("--mpc-min", type=open_fraction, default=0.8, metavar="MPC",
                   help="criterion 3: lowest modal phase collinearity of a kept root (default 0.8)")
    p.add_argument("--repeat-tol", type=positive_number, default=0.125, metavar="FRACTION",
                   help="criterion 4: a root's estimates in two bands agree within this fraction "
                   "of max(2 zeta f, line spacing) (default 0.125)")
    p.add_argument("--solver", choices=SOLVERS, default="ml",
                   help="step-1 solver in each band (default ml, as ssidlab identify)")
    p.add_argument("--scale", choices=SCALES, default="BP3",
                   help="scale factors of the model (--out): BP1 band, BP2 window, BP3 "
                   "global (default; section 5.2.2)")
    p.add_argument("--targets", metavar="FE_MODEL",
                   help="analysis model (ssidlab-model .h5, .mat or .op4) whose target modes "
                   "the model keeps first; its DOFs include every FRF output")
    p.add_argument("--target-modes", type=parse_mode_list, metavar="1,2,...",
                   help="the target modes of --targets, 1-based (default: its modes inside "
                   "the band)")
    p.add_argument("--no-residual-pair", action="store_true",
                   help="complete a model modes short without a residual pair fitted above "
                   "the band (its damping assumed), alone or with rigid-body modes")
    p.add_argument("--no-rigid-body", action="store_true",
                   help="complete a model modes short without rigid-body modes fitted to the "
                   "mass line below the band (free-free structures), alone or with a residual pair")
    p.add_argument("--quiet", action="store_true", help="do not print the mode table")
    p.set_defaults(run=run_bands)
    return p


def run_bands(args: argparse.Namespace) -> int:
    """Carry out ``ssidlab bands``; returns 0, raises InputError on bad input."""
    if args.fmin is not None and args.fmax is not None and args.fmin >= args.fmax:
        raise InputError(f"--fmin ({args.fmin:g} Hz) must be below --fmax ({args.fmax:g} Hz)")
    if args.target_modes is not None and args.targets is None:
        raise InputError("--target-modes needs --targets (the model the numbers refer to)")
    inputs = [args.frf] + ([args.targets] if args.targets else [])
    check_output_paths(inputs, [args.json, args.out, args.plot])

    # Imported here: input errors and --help must work even if the numerics cannot be imported.
    from ssid.bands import band_layout, plot_band_roots, process_bands
    from ssid.io import read_measured_frf, write_model
    from ssid.modal_model import modal_model_from_bands, modal_model_misfit_warning

    frf = read_measured_frf(args.frf)
    if frf.H_reaction is not None:
        raise InputError(f"{args.frf}: holds interface reactions; band processing with "
                         "reactions is not supported: over a narrow band, step 1 with reactions "
                         "is not determined (docs/algorithm.md, known limits); use ssidlab "
                         "identify, or measure the structure free (no reaction channels)")
    lo = float(frf.freq_hz[0]) if args.fmin is None else args.fmin
    hi = float(frf.freq_hz[-1]) if args.fmax is None else args.fmax
    data = frf.band(lo, hi)
    if data.n_freq < 2:
        raise InputError(f"{args.frf}: fewer than two frequency lines between {lo:g} and "
                         f"{hi:g} Hz (the file covers {frf.freq_hz[0]:g} to {frf.freq_hz[-1]:g} Hz)")
    targets = _target_modes(args, data) if args.targets else None

    f0, f1 = float(data.freq_hz[0]), float(data.freq_hz[-1])
    if args.width is not None and args.width > f1 - f0:
        raise InputError(f"--width {args.width:g} Hz is wider than the band used ({f0:g}-{f1:g} Hz)")
    # Default: one width on evenly spaced lines; equal line counts otherwise (width None).
    bands, width = band_layout(data, args.width, args.overlap)
    res = process_bands(data, bands, solver=args.solver, mpc_min=args.mpc_min,
                        repeat_tol=args.repeat_tol)
    if not any(d is not None for d in res.data):
        which = f"--width {width:g} Hz" if width is not None else f"{len(bands)} bands"
        raise InputError(f"{which}: no band holds enough lines for step 1 "
                         f"({data.n_freq} lines over {f0:g}-{f1:g} Hz); widen the bands")
    band_lines = [int(np.count_nonzero((data.freq_hz >= a) & (data.freq_hz <= b))) for a, b in bands]

    out: dict[str, Any] = {
        "source": args.frf,
        "settings": {"band_hz": [f0, f1], "width_hz": width, "band_lines": max(band_lines),
                     "overlap": args.overlap,
                     "mpc_min": args.mpc_min, "repeat_tol": args.repeat_tol,
                     "solver": args.solver},
        "bands_hz": [list(b) for b in res.bands_hz],
        # A band added after the layout's (ssid.band_edges.low_edge_band): its roots confirm
        # unresolved roots only.
        "low_edge_band": res.low_edge_band,
        # Its counterpart at the last line (ssid.band_edges.high_edge_band): also the third
        # estimate a mode found only by the nested top bands needs.
        "high_edge_band": res.high_edge_band,
        # Bands with fewer lines than step 1 needs are not fitted: their roots are missing.
        "skipped_bands": res.skipped,
        "min_lines": res.min_lines,
        "roots": [{"band": r.band, "freq_hz": r.freq_hz, "damping_ratio": r.zeta,
                   "mpc": r.mpc, "mpc_applied": r.mpc_applied,
                   "damping_applied": r.damping_applied, "verdict": r.rejected or "kept",
                   "mode": r.cluster}
                  for r in res.roots],
        "modes": _modes(res, targets),
    }
    if targets is not None:
        out["targets"] = {"source": args.targets, "mode_numbers": targets["numbers"],
                          "freq_hz": targets["freq_hz"].tolist()}
    if args.plot is not None:
        true_hz = None if targets is None else targets["freq_hz"]
        write_chart(args.plot, lambda path: plot_band_roots(path, res, true_hz))
    warnings: list[str] = list(res.warnings)
    if args.out is not None:
        try:
            model = modal_model_from_bands(
                data, res, scale=args.scale, band_width_hz=width,
                prefer_shapes=None if targets is None else targets["shapes"],
                prefer_freq_hz=None if targets is None else targets["freq_hz"],
                residual_pair=not args.no_residual_pair, rigid_body=not args.no_rigid_body)
        except IdentificationError as exc:
            # The bands' findings are kept (JSON, chart) even when no model can be made.
            out["model_error"] = str(exc)
            out["warnings"] = warnings
            write_json(args.json, out)
            for w in warnings:
                print(f"warning: {w}", file=sys.stderr)
            if not args.quiet:
                print(_table(out))
            hint = ("; another --scale may give positive modal masses (docs/algorithm.md, "
                    "known limits)" if "modal mass" in str(exc) else "")
            raise InputError(f"{args.frf}: no modal model ({exc}){hint}; the modes found are "
                             f"in {args.json}") from None
        try:
            write_model(args.out, model.to_model())
        except InputError as exc:  # our own result failing validation is a bug
            raise RuntimeError(f"modal model failed validation: {exc}") from exc
        out["model"] = {"path": args.out, "scale": args.scale, **model.to_json_dict()}
        warnings += model.warnings
        said = modal_model_misfit_warning(data, model)
        if said:
            warnings.append(said)
    out["warnings"] = warnings
    write_json(args.json, out)
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    if not args.quiet:
        print(_table(out))
    return 0


def _target_modes(args: argparse.Namespace, frf) -> dict:
    """The FE model's target modes at the FRF outputs: numbers (1-based), frequencies, shapes."""
    model, f_fe, phi = fe_normal_modes(args.targets)
    missing = [d for d in frf.outputs if d not in set(model.dofs)]
    if missing:
        raise InputError(f"{args.frf}: output {missing[0]!r} is not a DOF of the model "
                         f"{args.targets}")
    if args.target_modes is None:
        idx = np.flatnonzero((f_fe >= frf.freq_hz[0]) & (f_fe <= frf.freq_hz[-1]))
        if idx.size == 0:
            raise InputError(f"{args.targets}: no mode between {frf.freq_hz[0]:g} and "
                             f"{frf.freq_hz[-1]:g} Hz; name the targets with --target-modes")
    else:
        idx = np.asarray(args.target_modes) - 1
        if idx.max() >= f_fe.size:
            raise InputError(f"--target-modes: the model {args.targets} has {f_fe.size} modes")
    rows = [list(model.dofs).index(d) for d in frf.outputs]
    return {"numbers": [int(i) + 1 for i in idx], "freq_hz": f_fe[idx],
            "shapes": phi[np.ix_(rows, idx)]}


def _modes(res, targets: dict | None) -> list[dict]:
    """One entry per mode found: its representative root, how many bands found it, and the
    FE target it pairs with (MAC >= 0.8 and frequency), if any."""
    from ssid.band_scaling import root_shapes
    from ssid.correlate import modal_assurance, pair_modes_by_mac_and_frequency

    sel = res.selected
    paired: dict[int, tuple[int, float]] = {}
    if targets is not None and sel:
        n = len(targets["shapes"])
        mac = modal_assurance(root_shapes(sel, n), targets["shapes"])
        for p in pair_modes_by_mac_and_frequency(mac, res.freq_hz, targets["freq_hz"], 0.8):
            paired[p.test] = (targets["numbers"][p.analysis], float(mac[p.test, p.analysis]))
    modes = []
    for i, r in enumerate(sel):
        entry = {"freq_hz": r.freq_hz, "damping_ratio": r.zeta, "mpc": r.mpc,
                 "mpc_applied": r.mpc_applied, "band": r.band,
                 "n_bands": sum(1 for q in res.roots if q.cluster == r.cluster and not q.rejected)}
        if i in paired:
            entry["target_mode"], entry["target_mac"] = paired[i]
        modes.append(entry)
    return modes


def _table(out: dict) -> str:
    with_t = "targets" in out
    head = f"{'mode':>4}  {'f_n [Hz]':>12}  {'damping [%]':>11}  {'MPC':>6}  {'bands':>5}"
    verdicts: dict[str, int] = {}
    for r in out["roots"]:
        verdicts[r["verdict"]] = verdicts.get(r["verdict"], 0) + 1
    s = out["settings"]
    span = s["band_hz"][1] - s["band_hz"][0]
    if s["width_hz"] is None:
        size = f"{s['band_lines']} lines (uneven line spacing)"
    elif s["width_hz"] > span:
        # A record shorter than one band: the bands are the record and its parts.
        size = f"at most {span:.4g} Hz (the record is narrower than a {s['width_hz']:.4g} Hz band)"
    else:
        size = f"{s['width_hz']:.4g} Hz"
    n_bands = len(out["bands_hz"])
    low, high = out.get("low_edge_band"), out.get("high_edge_band")
    if low is not None:
        a, b = out["bands_hz"][low]
        size += f" and a low-edge band ({a:.4g}-{b:.4g} Hz) for roots below the line spacing"
        n_bands -= 1
    if high is not None:
        a, b = out["bands_hz"][high]
        size += f", and a high-edge band ({a:.4g}-{b:.4g} Hz) to confirm the top bands' roots"
        n_bands -= 1
    skipped = [b for b in out.get("skipped_bands", []) if b not in (low, high)]
    if skipped:
        # Said here, or "5 bands" would read as five fits when one was made.
        size += (f" ({len(skipped)} skipped: fewer than the {out['min_lines']} lines step 1 "
                 "needs)")
    lines = [f"{n_bands} band{'s' if n_bands != 1 else ''} of {size}; "
             f"{len(out['roots'])} roots (" + ", ".join(f"{v} {k}" for k, v in verdicts.items())
             + f"); {len(out['modes'])} mode{'s' if len(out['modes']) != 1 else ''} found",
             head + ("  target (MAC)" if with_t else "")]
    for k, m in enumerate(out["modes"], start=1):
        row = (f"{k:>4}  {m['freq_hz']:>12.4f}  {100 * m['damping_ratio']:>11.3f}  "
               f"{m['mpc']:>6.3f}{' ' if m['mpc_applied'] else '*'} {m['n_bands']:>5}")
        if with_t and "target_mode" in m:
            row += f"  {m['target_mode']} ({m['target_mac']:.3f})"
        lines.append(row)
    if not all(m["mpc_applied"] for m in out["modes"]):
        from ssid.band_criteria import PHASE_SEEN_HALF_WIDTHS

        lines.append(f"* MPC not applied: no line lies within {PHASE_SEEN_HALF_WIDTHS:g} half-power "
                     "half-widths of the mode, so the noise sets its shape's phase; kept as repeated "
                     "in another band")
    if "model" in out:
        held = out["model"].get("natural_freq_hz", [])
        err = (out["model"].get("checks") or {}).get("frf_relative_rms_error")
        # Stated on every model line, as pseudo-dof and identify do: the modes were each found
        # twice, but whether the matrices' FRFs reproduce the data is another question.
        fit = ("" if err is None else
               f"; its FRFs differ from the data by {100 * err:.3g} % (relative RMS)")
        lines.append(f"model: {len(held)} DOF ({out['model']['scale']}), modes "
                     + ", ".join(f"{f:.4g}" for f in held) + f" Hz -> {out['model']['path']}{fit}")
    return "\n".join(lines)
