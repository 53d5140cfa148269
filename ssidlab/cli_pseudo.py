"""``ssidlab pseudo-dof``: more modes than sensors with pseudo degrees of freedom (report 5.3).

    ssidlab pseudo-dof FRF.h5 --json RESULT.json [--out MODEL.h5 [--all-modes]]
                       [--partitions auto|P] [--plot STAB.png] [--consistency-min Q]
                       [--quiet]

The record is split into P partitions of equal length and these are stacked (Eq. 5.24, where
the report used P = 2): step 1 and the eigenproblem then give up to P times as many modes as
sensors. By default P is chosen from the data (``ssid.pseudo_dof_scan``): raised from 2
until the roots of the model and of the one with one partition more repeat each other. Each root is flagged structural
(in the band, positive damping, partition consistency >= ``--consistency-min``, and, with P
chosen, repeated) or computational. Step 2, which the report left open, is ours
(``ssid.pseudo_dof``): the
structural roots' scale factors are fitted to the measured FRFs, a root asking for a modal mass
<= 0 is no passive mode as fitted and is left out (still structural, counted apart), and
``--out`` writes M, C, K of the others: the n strongest
independent modes over the n measured DOFs, or with ``--all-modes`` every one of them over the
measured DOFs plus generalised coordinates ``q1, q2, ...`` the sensors do not see.
``docs/replication.md`` section 5 says how well this works on the payload (noise-free, and
under the report's noise, where the roots do not settle and a warning says so).

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
    open_fraction,
    whole_number,
    write_chart,
    write_json,
)

__all__ = ["add_pseudo_subcommand", "run_pseudo"]

HELP = ("Pseudo degrees of freedom (report section 5.3): more modes than sensors, structural "
        "and computational roots, and a modal M, C, K.")


def add_pseudo_subcommand(sub: Any) -> argparse.ArgumentParser:
    """Add the ``pseudo-dof`` subparser to ``sub`` (an argparse subparsers action)."""
    p = sub.add_parser("pseudo-dof", prog="ssidlab pseudo-dof", help=HELP, description=HELP,
                       allow_abbrev=False)
    p.add_argument("frf", metavar="FRF.h5",
                   help="measured FRFs (ssidlab-frf file, no reactions, no blanked values)")
    p.add_argument("--json", metavar="RESULT.json", required=True,
                   help="every root with its indicator and verdict (and the model)")
    p.add_argument("--out", metavar="MODEL.h5", help="M, C, K of the physical modes")
    p.add_argument("--all-modes", action="store_true",
                   help="with --out: every physical mode, over the measured DOFs and "
                   "generalised coordinates q1, q2, ... (default: the n strongest, n x n)")
    p.add_argument("--partitions", type=_partitions, default="auto", metavar="auto|P",
                   help="number of stacked partitions P >= 2 (the report's: 2), or auto: the "
                   "smallest P whose roots and P + 1's repeat each other (default auto)")
    p.add_argument("--consistency-min", type=open_fraction, default=0.8, metavar="Q",
                   help="partition consistency of a structural root (default 0.8)")
    p.add_argument("--plot", type=chart_file, metavar="STAB.png",
                   help="stabilisation diagram of the roots per number of partitions (PNG; "
                   "with --partitions auto)")
    p.add_argument("--quiet", action="store_true", help="do not print the root table")
    p.set_defaults(run=run_pseudo)
    return p


def _partitions(text: str) -> str | int:
    if text == "auto":
        return text
    try:
        return whole_number(text, 2)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected auto or an integer >= 2, got {text!r}") from None


def run_pseudo(args: argparse.Namespace) -> int:
    """Carry out ``ssidlab pseudo-dof``; returns 0, raises InputError on bad input."""
    if args.all_modes and args.out is None:
        raise InputError("--all-modes needs --out (it chooses the model written there)")
    if args.plot is not None and args.partitions != "auto":
        raise InputError("--plot draws the scan over the number of partitions: it needs "
                         "--partitions auto")
    check_output_paths([args.frf], [args.json, args.out, args.plot])
    # Imported here: input errors and --help must work even if the numerics cannot be imported.
    from ssid.fit_checks import misfits, relative_noise_level
    from ssid.io import Model, read_measured_frf, write_model
    from ssid.pseudo_dof import (
        flag_non_passive,
        frf_relative_error,
        identify_pseudo_dof,
        mck_accelerance,
        pseudo_dof_mck,
        pseudo_modal_model,
    )
    from ssid.pseudo_dof_scan import identify_pseudo_dof_auto, plot_partition_scan

    frf = read_measured_frf(args.frf)
    if frf.H_reaction is not None:
        raise InputError(f"{args.frf}: holds interface reactions; pseudo DOFs with reactions "
                         "are not supported (use ssidlab identify)")
    if not frf.valid_mask().all():
        raise InputError(f"{args.frf}: holds blanked values; pseudo DOFs need every line "
                         "(stacking pairs line k with line k + N/P)")
    try:
        if args.partitions == "auto":
            res = identify_pseudo_dof_auto(frf, consistency_min=args.consistency_min)
        else:
            res = identify_pseudo_dof(frf, consistency_min=args.consistency_min,
                                      n_partitions=args.partitions)
    except IdentificationError as exc:
        raise InputError(f"{args.frf}: {exc}") from None
    mass = np.full(res.freq_hz.size, np.nan)
    model = None
    if res.structural.any():
        try:
            model = pseudo_modal_model(frf, res)
        except (IdentificationError, np.linalg.LinAlgError) as exc:
            raise InputError(f"{args.frf}: the structural roots cannot be scaled ({exc})") from None
        mass[model.roots] = model.modal_mass
        # Structural, but no passive mode as fitted: left out of every model and counted apart.
        flag_non_passive(res, model)
    out: dict[str, Any] = {
        "source": args.frf,
        "n_partitions": res.n_partitions,
        "split_hz": res.split_hz.tolist(),
        "consistency_min": args.consistency_min,
        "roots": [{"freq_hz": res.freq_hz[k], "damping_ratio": res.zeta[k], "mpc": res.mpc[k],
                   "consistency": res.consistency[k],
                   "repeated": None if res.repeated is None else bool(res.repeated[k]),
                   "structural": bool(res.structural[k]),
                   "second_copy": res.second_copy is not None and bool(res.second_copy[k]),
                   "non_passive": res.non_passive is not None and bool(res.non_passive[k]),
                   "modal_mass": mass[k]} for k in range(res.freq_hz.size)],
    }
    warnings: list[str] = []
    if res.scan is not None:
        sc = res.scan
        out["partition_scan"] = {"n_partitions": sc.n_partitions.tolist(),
                                 "n_consistent": sc.n_consistent.tolist(),
                                 "n_repeated": sc.n_repeated.tolist(), "settled": sc.settled,
                                 "repeat_min": sc.repeat_min, "repeat_rtol": sc.repeat_rtol}
        if not sc.settled:
            warnings.append(
                f"the roots did not settle: at no P up to {sc.n_partitions[-1]} did "
                f"{100 * sc.repeat_min:.0f} % of its roots and of P + 1's repeat each other (noisy data?); P = "
                f"{sc.chosen} repeats most, and only its repeated roots are called structural. "
                "For noisy records band processing (ssidlab bands) is the better tool")
    if args.out is not None:
        if model is None:
            raise InputError(f"{args.frf}: no root is structural; no model to write")
        try:
            mck = pseudo_dof_mck(frf, model, n_keep=None if args.all_modes else frf.n_out)
        except IdentificationError as exc:
            # The roots exist even when no model can be made of them: their JSON and plot are
            # what the user needs to see why, so both are written before the refusal.
            write_json(args.json, out)
            where = args.json
            if args.plot is not None:
                write_chart(args.plot, lambda path: plot_partition_scan(path, res))
                where += f" and {args.plot}"
            raise InputError(f"{args.frf}: no model ({exc}); the roots are in {where}") from None
        n = frf.n_out
        dofs = list(frf.outputs) + [f"q{i}" for i in range(1, mck.M.shape[0] - n + 1)]
        write_model(args.out, Model(M=mck.M, K=mck.K, C=mck.C, dofs=dofs))
        H = mck_accelerance(mck.M, mck.C, mck.K, frf.omega, n, frf.input_index())
        err = frf_relative_error(H, frf.H)
        out["model"] = {"path": args.out, "dofs": dofs,
                        "modes_freq_hz": res.freq_hz[model.roots][mck.modes].tolist(),
                        "undamped_freq_hz": mck.undamped_freq_hz.tolist(),
                        "frf_relative_rms_error": err}
        # Stated with the model line; a warning only where it misses the data as identify's
        # misfit warning counts a miss (5 % and three times the data's noise): "warning: ... 0 %
        # off the data" on a model that reproduces them to round-off read as a fault.
        noise = relative_noise_level(frf)
        if misfits(err, noise):
            warnings.append(f"the model's FRFs at the measured DOFs are {100 * err:.3g} % off the data "
                            f"(relative RMS; the data's noise is about {100 * noise:.2g} %); "
                            "docs/replication.md section 5")
    write_json(args.json, out)
    if args.plot is not None:
        write_chart(args.plot, lambda path: plot_partition_scan(path, res))
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    if not args.quiet:
        print(_table(out))
    return 0


def _table(out: dict) -> str:
    scan = out.get("partition_scan")
    chosen = "" if scan is None else (" (chosen: its roots and one more's repeat each other)" if scan["settled"]
                                      else " (chosen, though the roots did not settle)")
    lines = [f"{out['n_partitions']} partitions{chosen}, split at "
             + ", ".join(f"{f:.4g}" for f in out["split_hz"]) + " Hz; "
             f"{len(out['roots'])} roots, {sum(r['structural'] for r in out['roots'])} structural"
             + _non_passive_note(out["roots"]),
             f"{'f_n [Hz]':>12}  {'damping [%]':>11}  {'MPC':>6}  {'consist.':>8}  "
             f"{'repeated':>8}  verdict"]
    for r in out["roots"]:
        verdict = ("structural, modal mass <= 0: not in the model" if r.get("non_passive") else
                   "structural" if r["structural"] else
                   "second copy of a structural root" if r.get("second_copy") else "computational")
        rep = "-" if r["repeated"] is None else ("yes" if r["repeated"] else "no")
        lines.append(f"{r['freq_hz']:>12.4f}  {100 * r['damping_ratio']:>11.3f}  "
                     f"{r['mpc']:>6.3f}  {r['consistency']:>8.3f}  {rep:>8}  {verdict}")
    if "model" in out:
        m = out["model"]
        lines.append(f"model: {len(m['dofs'])} DOF, modes "
                     + ", ".join(f"{f:.4g}" for f in m["undamped_freq_hz"]) + f" Hz -> {m['path']}; its FRFs "
                     f"differ from the data by {100 * m['frf_relative_rms_error']:.3g} % (relative RMS)")
    return "\n".join(lines)


def _non_passive_note(roots: list[dict]) -> str:
    """`` (1 with modal mass <= 0, left out of the model)`` when some structural roots are
    non-passive as fitted: "19 structural" must not read as 19 modes in the model."""
    k = sum(bool(r.get("non_passive")) for r in roots)
    return f" ({k} with modal mass <= 0, left out of the model)" if k else ""
