"""``ssidlab discrepancy``: find the effect a nominal model lacks, from measured FRFs.

    ssidlab discrepancy --model NOMINAL.h5 --measured FRF.h5 --json OUT.json
                        [--out UPDATED.h5] [--plots DIR] [--fmin HZ] [--fmax HZ]
                        [--max-effects 1|2] [--no-second-round] [--reactions auto|apply|ignore]
                        [--negligible PERCENT] [--quiet]

The JSON keys ``effect``, ``dofs``, ``parameters``, ``gap_before``, ``gap_after``,
``gap_metric`` and ``candidates`` are the contract's (``../shared/contract.md``); the others are
described in ``docs/discrepancy.md``. The nominal model may be an ssidlab-model ``.h5``, a
MATLAB ``.mat`` or a Nastran ``.op4`` file (``ssid.matrix_io.read_analysis_model``). Bad input
raises :class:`ssid.errors.InputError`; ``ssidlab.cli.main`` prints it as one line and exits
with status 2.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from typing import Any

from ssid.errors import InputError
from ssidlab.argtypes import check_output_paths, frequency_hz, percentage, write_chart, write_json

__all__ = ["add_discrepancy_subcommand", "run_discrepancy", "summary_text"]

#: ``ssid.reaction_loads.REACTION_CHOICES``, spelled out: this module imports no numerics at
#: load time (see run_discrepancy).
REACTION_CHOICES = ("auto", "apply", "ignore")

HELP = ("Find where a nominal model and measured FRFs disagree, name the missing effect, add it "
        "and show the gap shrink.")


def add_discrepancy_subcommand(sub: Any) -> argparse.ArgumentParser:
    """Add the ``discrepancy`` subparser to ``sub`` (an argparse subparsers action); returns it."""
    p = sub.add_parser("discrepancy", prog="ssidlab discrepancy", help=HELP, description=HELP,
                       allow_abbrev=False)
    p.add_argument("--model", metavar="NOMINAL.h5", required=True,
                   help="nominal model (ssidlab-model .h5, .mat or .op4); its DOFs include every "
                   "measured output")
    p.add_argument("--measured", metavar="FRF.h5", required=True,
                   help="measured FRFs (ssidlab-frf file)")
    p.add_argument("--json", metavar="OUT.json", required=True,
                   help="effect found, gaps before and after, ranked candidates")
    p.add_argument("--out", metavar="UPDATED.h5", help="write the nominal model with the effect added")
    p.add_argument("--plots", metavar="DIR", help="directory for PNG plots (created if needed)")
    p.add_argument("--reactions", choices=REACTION_CHOICES, default="auto",
                   help="FRFs measured on a test stand (with interface reactions): apply them to the "
                   "model (a model of the substructure alone), ignore them (a model that includes "
                   "the stand), or auto (default): the one that reproduces the data better")
    p.add_argument("--fmin", type=frequency_hz, metavar="HZ", help="lowest line used")
    p.add_argument("--fmax", type=frequency_hz, metavar="HZ", help="highest line used")
    p.add_argument("--max-effects", type=int, choices=(1, 2), default=1,
                   help="1: one effect (default); 2: also add a second effect if the second "
                   "round finds one")
    p.add_argument("--no-second-round", action="store_true",
                   help="do not check whether one effect closes the gap (faster)")
    p.add_argument("--negligible", type=percentage, metavar="PERCENT", default=0.1,
                   help="an effect that changes no model FRF value by this many per cent of the "
                   "value is negligible and not named (default 0.1, about 0.01 dB; 0 names any "
                   "effect the data show)")
    p.add_argument("--quiet", action="store_true", help="do not print the summary")
    p.set_defaults(run=run_discrepancy)
    return p




def _check_plot_dir(path: str, inputs: list[str]) -> None:
    if os.path.exists(path) and not os.path.isdir(path):
        raise InputError(f"{path}: exists and is not a directory (--plots)")
    if any(os.path.realpath(path) == os.path.realpath(s) for s in inputs):
        raise InputError(f"{path}: is an input file")


def run_discrepancy(args: argparse.Namespace) -> int:
    """Carry out ``ssidlab discrepancy``; returns 0, raises InputError on bad input."""
    if args.max_effects == 2 and args.no_second_round:
        # The second effect is what the second round finds: without it, 2 would be ignored.
        raise InputError("--max-effects 2 needs the second round, which --no-second-round leaves out")
    if args.fmin is not None and args.fmax is not None and args.fmin >= args.fmax:
        raise InputError(f"--fmin ({args.fmin:g} Hz) must be below --fmax ({args.fmax:g} Hz)")
    inputs = [args.model, args.measured]
    if os.path.realpath(args.model) == os.path.realpath(args.measured):
        raise InputError(f"{args.model}: given as both --model and --measured")
    check_output_paths(inputs, [args.json, args.out])
    if args.plots is not None:
        _check_plot_dir(args.plots, inputs)

    # Imported here: input errors and --help must work even if the numerics cannot be imported.
    from ssid.discrepancy import check_model, find_discrepancy
    from ssid.io import read_measured_frf, write_model
    from ssid.matrix_io import read_analysis_model

    model = read_analysis_model(args.model)
    try:
        check_model(model)
    except InputError as exc:
        raise InputError(f"{args.model}: {exc}") from None
    frf = read_measured_frf(args.measured)
    if args.reactions == "apply" and frf.H_reaction is None:
        # Nothing to apply: the model would be compared as it is, as with "ignore".
        raise InputError(f"{args.measured}: --reactions apply needs measured interface reactions "
                         "(H_reaction), and the file has none")
    lo = -math.inf if args.fmin is None else args.fmin
    hi = math.inf if args.fmax is None else args.fmax
    in_band = (frf.freq_hz >= lo) & (frf.freq_hz <= hi)
    if not in_band.any():
        raise InputError(f"{args.measured}: no frequency lines between --fmin and --fmax (the file "
                         f"covers {frf.freq_hz[0]:g} to {frf.freq_hz[-1]:g} Hz)")
    missing = [d for d in frf.outputs if d not in set(model.dofs)]
    if missing:
        raise InputError(f"{args.measured}: output {missing[0]!r} is not a DOF of the model {args.model}")

    result = find_discrepancy(model, frf, f_min_hz=args.fmin, f_max_hz=args.fmax,
                              max_effects=args.max_effects, second_round=not args.no_second_round,
                              reactions=args.reactions, negligible_change=args.negligible / 100.0)
    if args.out is not None:
        try:
            write_model(args.out, result.updated_model)
        except InputError as exc:
            # Our own model failing validation is a bug, not bad input: report it as internal.
            raise RuntimeError(f"updated model failed validation: {exc}") from exc
    data = result.to_json_dict()
    data["model_source"] = args.model
    data["measured_source"] = args.measured
    data["updated_model"] = args.out
    if args.plots is not None:
        from ssid.discrepancy.plots import write_plots

        data["plots"] = write_chart(args.plots, lambda path: write_plots(result, path), "the plots")
    write_json(args.json, data)
    # On stderr and also with --quiet (docs/formats.md): a warning such as "check the
    # transducers' calibration" must not be lost with the summary.
    for w in data.get("warnings", []):
        print(f"warning: {w}", file=sys.stderr)
    if not args.quiet:
        print(summary_text(data))
    return 0


def summary_text(data: dict) -> str:
    """A few lines for the terminal: the effect, the gap before and after, the runners-up."""
    pars = ", ".join(f"{k} = {v:.4g}" for k, v in data["parameters"].items())
    where = " - ".join(data["dofs"]) if data["dofs"] else ""
    lines = [f"effect: {data['effect']}" + (f" at {where}" if where else "") + (f" ({pars})" if pars else "")]
    effects = data.get("effects", [])
    for e in effects[1:]:  # --max-effects 2: the gap after is with every one added
        more = ", ".join(f"{k} = {v:.4g}" for k, v in e["parameters"].items())
        lines.append(f"  and: {e['effect']} at {' - '.join(e['dofs'])} ({more})")
    lines.append(f"gap ({data['gap_metric']}, 1 = noise level): {data['gap_before']:.4g} -> {data['gap_after']:.4g}")
    lines.append(data.get("residual", {}).get("text", ""))
    lines.append(data.get("reactions", {}).get("text", ""))
    lines.append("candidates (delta EBIC" + (", first round: one effect at a time):" if len(effects) > 1 else "):"))
    for c in data["candidates"][:6]:
        cp = ", ".join(f"{k} = {v:.4g}" for k, v in c["parameters"].items())
        # A rejected candidate's criterion was set to none's (+ 1e-9): its delta would print
        # as none's, a tie it is not.
        why = c.get("rejected")
        delta = "rejected" if why else f"{c['delta_criterion']:.1f}"
        lines.append(f"  {delta:>10}  {c['effect']:<20} {' - '.join(c['dofs']):<14} {cp}"
                     + (f"  ({why})" if why else ""))
    return "\n".join(x for x in lines if x)
