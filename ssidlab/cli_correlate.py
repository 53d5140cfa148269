"""``ssidlab correlate``: a test model or measured FRFs against an analysis model.

    ssidlab correlate --model TEST --model ANALYSIS [--tam guyan|irs|serep|hybrid|cb] ...
    ssidlab correlate --model ANALYSIS --frf FRF.h5 [--tam ...] ...

Models may be ssidlab-model ``.h5``, MATLAB ``.mat`` or Nastran ``.op4`` files
(:func:`ssid.matrix_io.read_analysis_model`). The JSON keys are defined in
``docs/correlation.md``. Bad input raises :class:`ssid.errors.InputError`; ``ssidlab.cli.main``
prints it as one line and exits with status 2.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from ssid.errors import InputError
from ssid.jsonutil import to_jsonable
from ssid.reaction_loads import REACTION_CHOICES
from ssid.tam import TAM_METHODS
from ssidlab.argtypes import check_output_paths, frequency_hz, label_list, open_fraction, parse_mode_list, write_json

__all__ = ["add_correlate_subcommand", "jsonable", "parse_mode_list", "run_correlate"]

HELP = "Correlate a test model or measured FRFs with an analysis model (MAC, orthogonality, FRAC)."


# ----------------------------------------------------------------------------------------------
# Parser
# ----------------------------------------------------------------------------------------------


def add_correlate_subcommand(sub: Any) -> argparse.ArgumentParser:
    """Add the ``correlate`` subparser to ``sub`` (an argparse subparsers action); returns it."""
    p = sub.add_parser("correlate", prog="ssidlab correlate", help=HELP, description=HELP,
                       allow_abbrev=False)
    p.add_argument(
        "--model", action="append", metavar="MODEL", required=True,
        help="model file (.h5 ssidlab-model, .mat, .op4). Twice: the test (identified) model, "
        "then the analysis model, whose DOFs must include the test DOFs. Once, with --frf: the "
        "analysis model",
    )
    p.add_argument("--frf", metavar="FRF.h5", help="measured FRFs (ssidlab-frf file)")
    p.add_argument(
        "--tam", choices=TAM_METHODS, default=None,
        help="test-analysis model reducing the analysis model to the test DOFs (default guyan)",
    )
    p.add_argument("--interface", type=label_list, metavar="DOF[,DOF...]",
                   help="interface (boundary) DOF labels; needed by --tam cb")
    p.add_argument("--targets", type=parse_mode_list, metavar="LIST",
                   help="target modes of serep/hybrid/cb, 1-based analysis mode numbers, e.g. "
                   "'1-10,17,18' (default: the lowest as many as test DOFs)")
    p.add_argument("--zeta", type=_damping_ratio, default=None, metavar="RATIO",
                   help="modal damping ratio for a model without C, with --frf (default 0.02)")
    p.add_argument("--reactions", choices=REACTION_CHOICES, default=None,
                   help="--frf measured on a test stand (with interface reactions): apply them to the "
                   "model (a model of the substructure alone), ignore them (a model that includes "
                   "the stand), or auto (default): the one that reproduces the data better")
    p.add_argument("--fmin", type=frequency_hz, metavar="HZ", help="lowest line compared (--frf)")
    p.add_argument("--fmax", type=frequency_hz, metavar="HZ", help="highest line compared (--frf)")
    p.add_argument("--json", metavar="OUT.json", required=True, help="correlation results")
    p.add_argument("--plots", metavar="DIR", help="directory for PNG plots (created if needed)")
    p.add_argument("--quiet", action="store_true", help="do not print the paired-mode table")
    p.set_defaults(run=run_correlate)
    return p


def _damping_ratio(text: str) -> float:
    return open_fraction(text, "a damping ratio")


# ----------------------------------------------------------------------------------------------
# Run
# ----------------------------------------------------------------------------------------------


def run_correlate(args: argparse.Namespace) -> int:
    """Carry out ``ssidlab correlate``; returns 0, raises InputError on bad input."""
    models = list(args.model or [])
    if len(models) > 2:
        raise InputError("--model is given more than twice (test model, analysis model)")
    if len(models) == 2 and args.frf:
        raise InputError("give either a second --model or --frf, not both")
    if len(models) == 1 and not args.frf:
        raise InputError("give a second --model (the analysis model) or --frf (measured FRFs)")
    if not args.frf and (args.fmin is not None or args.fmax is not None):
        raise InputError("--fmin and --fmax apply to --frf only")
    if not args.frf and (args.zeta is not None or args.reactions is not None):
        raise InputError("--zeta and --reactions apply to --frf only")
    # Options a TAM does not use were ignored without a word (the audit): said, as --fmin is.
    tam = args.tam or "guyan"
    if args.targets is not None and tam not in ("serep", "hybrid", "cb"):
        raise InputError(f"--targets applies to --tam serep, hybrid or cb; --tam {tam} uses no target modes")
    if args.interface is not None and tam != "cb":
        raise InputError(f"--interface applies to --tam cb only; --tam {tam} has no interface DOFs")
    if args.fmin is not None and args.fmax is not None and args.fmin >= args.fmax:
        raise InputError(f"--fmin ({args.fmin:g} Hz) must be below --fmax ({args.fmax:g} Hz)")
    sources = models + ([args.frf] if args.frf else [])
    check_output_paths(sources, [args.json])
    if args.plots is not None:
        _check_plot_dir(args.plots, sources)

    from ssid.correlate_models import correlate_models, correlate_with_frf
    from ssid.io import read_measured_frf
    from ssid.matrix_io import read_analysis_model

    analysis = read_analysis_model(models[0] if args.frf else models[1])
    if args.targets is not None and max(args.targets) > analysis.n:
        raise InputError(f"--targets: mode {max(args.targets)} but the analysis model has "
                         f"{analysis.n} modes")
    if args.frf:
        test_source, analysis_source = args.frf, models[0]
        if args.zeta is not None and analysis.C is not None:
            raise InputError(f"--zeta: {models[0]} has its own damping matrix C, which is used; "
                             "--zeta applies to a model without C")
        frf = read_measured_frf(args.frf)
        if args.reactions == "apply" and frf.H_reaction is None:
            raise InputError(f"{args.frf}: --reactions apply needs measured interface reactions "
                             "(H_reaction), and the file has none")
        _require_dofs_in(frf.outputs, "output", args.frf, analysis.dofs, models[0])
        _require_a_reduction_for(args, frf.outputs, analysis.n, models[0])
        with _models_named(test_source, analysis_source):
            study = correlate_with_frf(
                frf, analysis, tam=tam, interface=args.interface, targets=args.targets,
                zeta=0.02 if args.zeta is None else args.zeta, f_min_hz=args.fmin, f_max_hz=args.fmax,
                reactions=args.reactions or "auto",
            )
    else:
        test_source, analysis_source = models[0], models[1]
        test = read_analysis_model(models[0])
        _require_dofs_in(test.dofs, "DOF", models[0], analysis.dofs, models[1])
        _require_a_reduction_for(args, test.dofs, analysis.n, models[1])
        with _models_named(test_source, analysis_source):
            study = correlate_models(test, analysis, tam=tam, interface=args.interface,
                                     targets=args.targets)
    summary = {"test_source": test_source, "analysis_source": analysis_source, **study.summary}
    summary["plots"] = _write_plots(study, args.plots) if args.plots is not None else []
    write_json(args.json, summary)
    # On stderr and also with --quiet (docs/formats.md), not in the table --quiet leaves out.
    for w in summary.get("warnings", []):
        print(f"warning: {w}", file=sys.stderr)
    if not args.quiet:
        print(pair_table(summary))
    return 0


def _require_a_reduction_for(args: argparse.Namespace, test_dofs: list[str], n_analysis: int,
                             analysis_source: str) -> None:
    """An analysis model over the test DOFs alone is compared as it is, with no TAM: a TAM
    option given then is refused, as the others no comparison uses are (``--tam serep
    --targets 1-3`` passed, and the JSON listed targets no reduction had used)."""
    given = [name for name, value in (("--tam", args.tam), ("--targets", args.targets),
                                      ("--interface", args.interface)) if value is not None]
    if any(d not in test_dofs for d in args.interface or []):
        return  # a mistyped interface label: the library names it, the first thing to mend
    if given and len(test_dofs) == n_analysis:
        raise InputError(f"{analysis_source} has only the test DOFs: no TAM is made, so {', '.join(given)} "
                         f"{'is' if len(given) == 1 else 'are'} not used")


def _require_dofs_in(dofs: list[str], kind: str, source: str, analysis_dofs: list[str], analysis_source: str) -> None:
    """The library refuses test DOFs the analysis model lacks; here the message names both files."""
    missing = [d for d in dofs if d not in set(analysis_dofs)]
    if missing:
        raise InputError(f"{source}: {kind} {missing[0]!r} is not a DOF of the analysis model {analysis_source}")


@contextmanager
def _models_named(test_source: str, analysis_source: str) -> Iterator[None]:
    """The library's errors about a model begin "test model:" or "analysis model:"; the
    user needs to know which file that is."""
    try:
        yield
    except InputError as exc:
        msg = str(exc)
        for who, path in (("analysis model", analysis_source), ("test model", test_source)):
            if msg.startswith(who + ":"):
                raise InputError(f"{path} ({who}):{msg[len(who) + 1:]}") from None
        raise


def _check_plot_dir(path: str, sources: list[str]) -> None:
    if os.path.exists(path) and not os.path.isdir(path):
        raise InputError(f"{path}: exists and is not a directory (--plots)")
    if any(os.path.realpath(path) == os.path.realpath(s) for s in sources):
        raise InputError(f"{path}: is an input file")


def _safe(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9._+-]", "_", label)


def _write_plots(study: Any, directory: str) -> list[str]:
    from ssid.plots_correlation import (
        plot_cmif,
        plot_frequency_errors,
        plot_frf_overlay,
        plot_mac_matrix,
    )

    d = Path(directory)
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{directory}: cannot create the plot directory ({exc.strerror or exc})") from None
    s = study.summary
    out = []
    if study.mac.size:
        out.append(plot_mac_matrix(study.mac, d / "mac.png", study.test_freq_hz,
                                   study.analysis_freq_hz, title=f"MAC (TAM: {s['tam']})"))
    if s["paired_modes"]:
        out.append(plot_frequency_errors(s["paired_modes"], d / "freq_errors.png"))
    if study.frf_test is not None:
        t, m = study.frf_test, study.frf_model
        out.append(plot_cmif(t.freq_hz, study.cmif_test, study.cmif_model, d / "cmif.png",
                             peaks_hz=study.test_freq_hz))
        valid = t.valid_mask()
        # Drive points: one overlay per input, at its own output DOF.
        for j, lbl in enumerate(t.inputs):
            i = t.outputs.index(lbl)
            out.append(plot_frf_overlay(
                t.freq_hz, t.H[:, i, j], m.H[:, i, j], d / f"frf_{_safe(lbl)}_{_safe(lbl)}.png",
                title=f"drive point {lbl}  (FRAC {s['frac']['matrix'][i][j]:.3f})",
                valid=valid[:, i, j],
            ))
    return out


def pair_table(summary: dict) -> str:
    """Text table of the paired modes."""
    lines = [
        f"TAM: {summary['tam']}   paired modes: {len(summary['paired_modes'])}",
        (f"{'test':>4} {'f_test [Hz]':>12} {'anal':>4} {'f_anal [Hz]':>12} "
         f"{'err [%]':>9} {'MAC':>6} {'XOR':>7}"),
    ]
    for p in summary["paired_modes"]:
        # A term the TAM mass cannot judge (ssid.correlate_scope) in brackets: kept, not counted.
        xo = f"{p['cross_orthogonality']:.3f}"
        lines.append(f"{p['test_mode']:>4} {_fixed(p['test_freq_hz'], 4):>12} {p['analysis_mode']:>4} "
                     f"{_fixed(p['analysis_freq_hz'], 4):>12} {_error(p):>9} {p['mac']:>6.3f} "
                     f"{xo if p.get('cross_orthogonality_applicable', True) else f'({xo})':>7}")
    if not all(p.get("cross_orthogonality_applicable", True) for p in summary["paired_modes"]):
        lines.append("(XOR): not applicable (the warnings say why), not counted in the verdict")
    if any(p.get("rigid") for p in summary["paired_modes"]):
        lines.append("rigid: paired with an analysis mode at 0 Hz (rigid-body), whose error is no percentage")
    for g in summary.get("subspaces") or []:
        rest = " (at rest)" if g["at_rest"] else ""
        angles = f"  principal angles {', '.join(f'{a:.2g}' for a in g['principal_angles_deg'])} deg; "
        if g.get("rotated", "test") == "test":
            lines.append(f"test modes {_numbers(g['test_modes'])}{rest} share a frequency, as analysis modes "
                         f"{_numbers(g['analysis_modes'])} do: compared as subspaces")
            lines.append(f"{angles}test modes rotated within their span onto analysis modes "
                         f"{_numbers(g['aligned_with'])} ({g['weighting']})")
        else:  # distinct test modes: the analysis group's basis is the one turned
            lines.append(f"analysis modes {_numbers(g['analysis_modes'])}{rest} share a frequency, test modes "
                         f"{_numbers(g['test_modes'])} do not (distinct modes): compared as subspaces")
            lines.append(f"{angles}analysis modes rotated within their span onto test modes "
                         f"{_numbers(g['aligned_with'])} ({g['weighting']})")
    refused = summary.get("not_paired") or []
    if refused:
        # Below the pairs, apart from them: a row among them would read as a pair (the QA's
        # 54.57 Hz test mode "paired" with the 1.29 Hz analysis mode, 4140 % off).
        lines.append("not paired (the best MAC of each, and why it is no pair):")
        for p in refused:
            negative = p["test_freq_hz"] < 0 and "omega^2 < 0" in p["reason"]
            f_test = "omega^2 < 0" if negative else _fixed(p["test_freq_hz"], 4)
            if "analysis_mode" not in p:
                lines.append(f"{p['test_mode']:>4} {f_test:>12}  {p['reason']}")
                continue
            err = "-" if negative else _error(p, 1)
            f_an = _fixed(p['analysis_freq_hz'], 4)
            lines.append(f"{p['test_mode']:>4} {f_test:>12} {p['analysis_mode']:>4} {f_an:>12} "
                         f"{err:>9} {p['mac']:>6.3f}  {p['reason']}")
    xo = summary["cross_orthogonality"]
    if xo["min_abs_diag"] is None:  # nothing paired: no numbers to show, only the verdict
        why = "above, why" if refused else "there are no test modes"
        lines.append(f"cross-orthogonality: no modes were paired ({why}) -> fail")
    else:
        lines.append(f"cross-orthogonality: min |diag| {xo['min_abs_diag']:.3f}, max |off-diag| "
                     f"{xo['max_abs_offdiag']:.3f} -> {_verdict(xo)}")
    o = summary.get("orthogonality") or {}
    if o.get("max_abs_offdiag") is not None:
        lines.append(f"orthogonality of the test modes: max |off-diag| {o['max_abs_offdiag']:.3f} -> {_verdict(o)}")
    if "frf_gap" in summary:
        lines.append(f"FRAC mean {summary['frac']['mean']:.3f}, gap ({summary['frf_gap_metric']}) "
                     f"{summary['frf_gap']:.4g}, {summary['frf_gap_db']:.3g} dB rms")
    if summary.get("reactions", {}).get("text"):
        lines.append(summary["reactions"]["text"])
    return "\n".join(lines)


def _error(p: dict, digits: int = 3) -> str:
    """A record's frequency error for the table: "rigid" against an analysis mode at 0 Hz."""
    return "rigid" if p.get("rigid") else _fixed(p["freq_error_percent"], digits)


def _fixed(x: float, digits: int) -> str:
    """``x`` with ``digits`` decimals, without the sign of a value that rounds to zero: a
    rigid-body mode at -3e-6 Hz printed as "-0.0000", an exact error as "-0.000"."""
    text = f"{x:.{digits}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text


def _verdict(check: dict) -> str:
    """pass, fail, or "not applicable (see the warnings)": more shapes than DOFs, or shapes
    outside a singular TAM mass's range, cannot be mass-orthogonal (ssid.correlate_scope)."""
    if check.get("status") == "not applicable":
        return "not applicable (the warnings say why)"
    return "pass" if check["pass"] else "fail"


def _numbers(modes: list[int]) -> str:
    return ", ".join(str(k) for k in modes)


def jsonable(obj: Any) -> Any:
    """Kept for callers of this module: see :func:`ssid.jsonutil.to_jsonable`."""
    return to_jsonable(obj)
