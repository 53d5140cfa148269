"""``ssidlab place``: where to put the accelerometers, from the analysis model (report Eq. 6.1).

    ssidlab place FE_MODEL --sensors N --json OUT.json [--targets 1-10,17] [--direction Z]
                  [--candidates 1+Z,2+Z,...] [--require 4+Z,8+Z] [--quiet]

Effective Independence (``ssid.placement.effective_independence``): of the candidate DOFs,
keep the N that best observe the target modes, removing one at a time the DOF that adds least
to the determinant of the Fisher information ``F = Phi^T Phi``. Candidates are the model's
translational DOFs (what an accelerometer measures), or those of one direction, or a list;
``--require`` keeps the DOFs a test must measure anyway (driving points, interface DOFs).
Targets the candidates cannot observe (a target that vanishes at every candidate, or shapes
there of lower rank than the targets: F singular for every choice) are refused. It
prints the chosen DOFs and, for the targets at those DOFs, the largest off-diagonal auto-MAC
(targets the sensors cannot tell apart) and the condition number of F.

Bad input raises :class:`ssid.errors.InputError`; ``ssidlab.cli.main`` prints it as one line
and exits with status 2.
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from ssid.errors import InputError
from ssidlab.argtypes import (
    check_output_paths,
    fe_normal_modes,
    label_list,
    parse_mode_list,
    whole_number,
    write_json,
)

__all__ = ["add_place_subcommand", "run_place"]

HELP = ("Choose sensor DOFs for target modes from an analysis model (Effective Independence, "
        "report Eq. 6.1).")
TRANSLATIONS = ("X", "Y", "Z")


def add_place_subcommand(sub: Any) -> argparse.ArgumentParser:
    """Add the ``place`` subparser to ``sub`` (an argparse subparsers action); returns it."""
    p = sub.add_parser("place", prog="ssidlab place", help=HELP, description=HELP,
                       allow_abbrev=False)
    p.add_argument("model", metavar="FE_MODEL",
                   help="analysis model (ssidlab-model .h5, .mat or .op4) with DOF labels")
    p.add_argument("--sensors", type=whole_number, required=True, metavar="N",
                   help="number of DOFs to measure (at least the number of target modes)")
    p.add_argument("--json", metavar="OUT.json", required=True,
                   help="chosen DOFs, targets and the checks of the choice")
    p.add_argument("--targets", type=parse_mode_list, metavar="LIST",
                   help="target modes, 1-based, e.g. '1-10,17,18' (default: the lowest N)")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--direction", choices=TRANSLATIONS,
                       help="candidates: the translations in this direction only")
    which.add_argument("--candidates", type=label_list, metavar="LABELS",
                       help="candidates: these DOFs (default: every translational DOF)")
    p.add_argument("--require", type=label_list, metavar="LABELS",
                   help="DOFs always kept (driving points, interface DOFs)")
    p.add_argument("--quiet", action="store_true", help="do not print the chosen DOFs")
    p.set_defaults(run=run_place)
    return p


def run_place(args: argparse.Namespace) -> int:
    """Carry out ``ssidlab place``; returns 0, raises InputError on bad input."""
    check_output_paths([args.model], [args.json])
    # Imported here: input errors and --help must work even if the numerics cannot be imported.
    from ssid.correlate import auto_mac
    from ssid.placement import effective_independence

    model, f_hz, phi = fe_normal_modes(args.model)
    dofs = list(model.dofs)
    if args.candidates is not None:
        unknown = [d for d in args.candidates if d not in dofs]
        if unknown:
            raise InputError(f"--candidates: {unknown[0]!r} is not a DOF of {args.model}")
        cand = list(args.candidates)
    else:
        dirs = (args.direction,) if args.direction else TRANSLATIONS
        cand = [d for d in dofs if d.rpartition("+")[2] in dirs]
        if not cand:
            raise InputError(f"{args.model}: no DOF labelled '<node>+{'|'.join(dirs)}' to "
                             "choose from; list them with --candidates")
    for r in args.require or []:
        if r not in cand:
            raise InputError(f"--require: {r!r} is not among the candidate DOFs")
    n_modes = f_hz.size
    targets = (np.asarray(args.targets) - 1 if args.targets is not None
               else np.arange(min(args.sensors, n_modes)))
    if targets.max() >= n_modes:
        raise InputError(f"--targets: {args.model} has {n_modes} modes")
    if not targets.size <= args.sensors <= len(cand):
        raise InputError(f"--sensors {args.sensors}: must lie between the number of target "
                         f"modes ({targets.size}) and of candidate DOFs ({len(cand)})")
    if len(args.require or []) > args.sensors:
        raise InputError(f"--require lists {len(args.require)} DOFs, more than --sensors "
                         f"{args.sensors}")
    rows = [dofs.index(d) for d in cand]
    # Refused (InputError) when the candidates cannot observe the targets: a target judged
    # against its own shape over the whole model, named by number and frequency.
    chosen = effective_independence(
        phi[np.ix_(rows, targets)], args.sensors, cand, required=args.require,
        mode_names=[f"{t + 1} ({f_hz[t]:.4g} Hz)" for t in targets],
        mode_norms=np.linalg.norm(phi[:, targets], axis=0))
    phi_a = phi[np.ix_([dofs.index(d) for d in chosen], targets)]
    am = auto_mac(phi_a)
    pair = None  # the two targets the chosen DOFs tell apart least (none for one target)
    if targets.size > 1:
        # Over pairs of two different targets only: with every off-diagonal term 0 (modes
        # at disjoint DOFs) an argmax over the zeroed matrix named "modes 1 and 1".
        upper_i, upper_j = np.triu_indices(targets.size, k=1)
        k = int(np.argmax(am[upper_i, upper_j]))
        i, j = upper_i[k], upper_j[k]
        pair = {"value": float(am[i, j]), "modes": [int(targets[i]) + 1, int(targets[j]) + 1]}
    sv = np.linalg.svd(phi_a, compute_uv=False)
    out = {
        "source": args.model,
        "chosen": chosen,
        "required": list(args.require or []),
        "n_candidates": len(cand),
        "targets": {"mode_numbers": [int(t) + 1 for t in targets],
                    "freq_hz": f_hz[targets].tolist()},
        "fisher_condition": float((sv[0] / sv[-1]) ** 2) if sv[-1] > 0 else None,
        "max_offdiag_auto_mac": pair,
    }
    write_json(args.json, out)
    if not args.quiet:
        print(f"{len(chosen)} of {len(cand)} candidate DOFs for {targets.size} target modes "
              f"({f_hz[targets].min():.4g}-{f_hz[targets].max():.4g} Hz): {', '.join(chosen)}")
        print(("largest auto-MAC between targets at these DOFs: "
               f"{pair['value']:.3f} (modes {pair['modes'][0]} and {pair['modes'][1]})"
               if pair else "one target: no auto-MAC")
              + "; condition of F: "
              + (f"{out['fisher_condition']:.3g}" if out["fisher_condition"] else "inf"))
    return 0
