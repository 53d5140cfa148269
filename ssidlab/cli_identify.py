"""``ssidlab identify``: M, C, K of a substructure from a measured FRF file (SSID).

    ssidlab identify FRF.h5 --out MODEL.h5 --json RESULT.json [--solver ml|ls|tls|stls]
                     [--fmin HZ] [--fmax HZ] [--damping auto|identified|modal]
                     [--select-band] [--reactions apply|ignore] [--quiet]

Writes the identified model (ssidlab-model file) over the FRF file's outputs and the modal
results and fit details as JSON (``docs/formats.md``); prints the modes and how far the written
model's FRFs are from the data. Bad input raises :class:`ssid.errors.InputError`;
``ssidlab.cli.main`` prints it as one line and exits with status 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from typing import Any

from ssid.errors import IdentificationError, InputError
from ssid.io import read_measured_frf, write_model
from ssidlab.argtypes import check_output_paths, frequency_hz, say, write_json

__all__ = ["add_identify_subcommand", "run_identify"]

HELP = "Identify M, C, K from a measured FRF file (SSID)."
DESCRIPTION = (HELP + " On a test stand, the FRF file's interface reactions (load cells) are applied as the "
               "forces the stand exerts, so M, C, K are the substructure's alone, without the stand "
               "(--reactions ignore: leave them out); the load cells are checked against the accelerances.")
REACTION_CHOICES = ("apply", "ignore")
SOLVERS = ("ml", "ls", "tls", "stls")  # ssid.identify.SOLVERS, without importing the solver stack
DAMPING_CHOICES = ("auto", "identified", "modal")  # ssid.identify.DAMPING_OPTIONS
# What each written C is, for the summary line (docs/formats.md, identify's damping_matrix).
_DAMPING_WORDS = {"identified": " (Eq. 3.15)", "modal": " (the roots' damping ratios on the real modes)",
                  "step1": " (step 1's M^-1 C on the written M)",
                  "output_error": " (M, C, K refined together to the data by output error)"}


def add_identify_subcommand(sub: Any) -> argparse.ArgumentParser:
    """Add the ``identify`` subparser to ``sub`` (an argparse subparsers action); returns it."""
    p = sub.add_parser("identify", prog="ssidlab identify", help=HELP, description=DESCRIPTION,
                       allow_abbrev=False)
    p.add_argument("frf", metavar="FRF.h5", help="measured FRFs (ssidlab-frf file)")
    p.add_argument(
        "--out", metavar="MODEL.h5", required=True,
        help="identified model (ssidlab-model file) over the FRF file's output DOFs",
    )
    p.add_argument(
        "--json", metavar="RESULT.json", required=True,
        help="natural frequencies, damping ratios and fit details",
    )
    p.add_argument(
        "--solver", choices=SOLVERS, default=None,
        help="ml: maximum likelihood, weights each line by its noise (default); "
        "ls: least squares; tls: total least squares; stls: scaled total least squares",
    )
    p.add_argument("--fmin", type=frequency_hz, metavar="HZ", help="lowest frequency line used")
    p.add_argument("--fmax", type=frequency_hz, metavar="HZ", help="highest frequency line used")
    p.add_argument(
        "--damping", choices=DAMPING_CHOICES, default="auto",
        help="identified: C from the identified state-space matrices; modal: C rebuilt from "
        "the identified damping ratios on the real modes; auto (default): the one whose model "
        "reproduces the measured FRFs better",
    )
    p.add_argument(
        "--select-band", action="store_true",
        help="reduced-order model (more modes in the band than sensors): choose the band and "
        "solver from the data, the band-processed modal model when it is physical "
        "(docs/algorithm.md); the solver is then chosen too",
    )
    p.add_argument(
        "--reactions", choices=REACTION_CHOICES, default=None,
        help="FRFs measured on a test stand (with interface reactions): apply them, so the model is the "
        "substructure alone (default when the file has them), or ignore them (the fit then sees the "
        "stand's loads as part of the structure)",
    )
    p.add_argument("--quiet", action="store_true", help="do not print the mode table")
    p.set_defaults(run=run_identify)
    return p


def run_identify(args: argparse.Namespace) -> int:
    """Run ``ssidlab identify``; returns the exit status (0). Bad input raises InputError."""
    # Cheap checks first, so a typo does not cost an identification run.
    if args.select_band and args.solver is not None:
        raise InputError("--select-band chooses the solver from the data; leave out --solver")
    if args.fmin is not None and args.fmax is not None and args.fmin >= args.fmax:
        raise InputError(f"--fmin ({args.fmin:g} Hz) must be below --fmax ({args.fmax:g} Hz)")
    check_output_paths([args.frf], [args.out, args.json])
    frf = read_measured_frf(args.frf)
    _check_band(args.frf, frf, args.fmin, args.fmax)
    in_file = list(frf.reactions or []) if frf.H_reaction is not None else []
    if args.reactions == "apply" and not in_file:
        raise InputError(f"{args.frf}: --reactions apply needs measured interface reactions (the file has none)")
    if args.reactions == "ignore" and in_file:
        frf = dataclasses.replace(frf, H_reaction=None, H_reaction_var=None, reactions=None)
    applied = in_file if frf.H_reaction is not None else []

    # Imported here: the solver stack is heavy, and input errors and --help must work even
    # when it cannot be imported.
    from ssid.identify import identify_mck

    try:
        if args.select_band:
            from ssid.band_select import identify_mck_band_select

            lo = float(frf.freq_hz[0]) if args.fmin is None else args.fmin
            hi = float(frf.freq_hz[-1]) if args.fmax is None else args.fmax
            result = identify_mck_band_select(frf.band(lo, hi), damping=args.damping)
        else:
            result = identify_mck(
                frf, solver=args.solver or "ml", f_min_hz=args.fmin, f_max_hz=args.fmax,
                damping=args.damping,
            )
    except IdentificationError as exc:  # what the data cannot give: say which data
        raise IdentificationError(f"{args.frf}: {exc}") from None
    if list(result.dofs) != frf.outputs:
        raise RuntimeError(
            f"identified model DOFs {list(result.dofs)!r} differ from the FRF outputs "
            f"{frf.outputs!r}"
        )
    try:
        model = result.to_model()
        model.attrs = _provenance(args, summary_band=result.band_hz, applied=applied, in_file=in_file,
                                  solver=result.solver, damping=result.damping)
        write_model(args.out, model)
    except InputError as exc:
        # Our own result failing validation is a bug, not bad input: report it as internal.
        raise RuntimeError(f"identified model failed validation: {exc}") from exc
    summary = result.to_json_dict()
    summary["reactions"] = {"in_file": in_file, "applied": applied, "text": _reactions_text(in_file, applied)}
    write_json(args.json, summary)

    for message in result.warnings:
        say(f"warning: {message}")
    if not args.quiet:
        choice = ((summary.get("info") or {}).get("band_select") or {}).get("choice")
        if choice and choice not in result.warnings:
            print(choice)
        if in_file:
            print(summary["reactions"]["text"])
        print(_mode_table(summary))
        err = (summary.get("checks") or {}).get("frf_relative_rms_error")
        if err is not None:
            which = summary.get("damping_matrix")
            print(f"written model: damping matrix {which}{_DAMPING_WORDS.get(which, '')}; its FRFs differ "
                  f"from the data by {_fmt(err, 100.0, '.3g')} % (relative RMS over the band)")
    return 0


def _reactions_text(in_file: list[str], applied: list[str]) -> str:
    """One line saying what the model is: the substructure alone, or with the stand's loads in it."""
    if applied:
        return (f"reactions applied at {', '.join(applied)}: M, C, K are the substructure alone, without the stand "
                "(--reactions ignore to leave them out)")
    if in_file:
        return (f"reactions at {', '.join(in_file)} not applied (--reactions ignore): the stand's loads are in the "
                "fit, M, C, K are not the substructure's alone")
    return ""


def _provenance(args: argparse.Namespace, summary_band: tuple[float, float], applied: list[str],
                in_file: list[str], solver: str, damping: str) -> dict:
    """Root attributes of the written model file: where it came from (contract: extra root attrs
    are provenance; reading ignores them)."""
    import os

    from ssidlab import __version__

    return {"created_by": "ssidlab identify", "ssidlab_version": __version__,
            "source_frf": os.path.abspath(args.frf), "band_hz": [float(summary_band[0]), float(summary_band[1])],
            "solver": solver, "damping_matrix": damping, "select_band": bool(args.select_band),
            "reactions_in_file": ",".join(in_file), "reactions_applied": ",".join(applied)}


def _check_band(source: str, frf, f_min: float | None, f_max: float | None) -> None:
    lo = -math.inf if f_min is None else f_min
    hi = math.inf if f_max is None else f_max
    in_band = (frf.freq_hz >= lo) & (frf.freq_hz <= hi)
    covers = f"the file covers {frf.freq_hz[0]:g} to {frf.freq_hz[-1]:g} Hz"
    if not in_band.any():
        raise InputError(f"{source}: no frequency lines between --fmin and --fmax ({covers})")
    if not frf.valid_mask()[in_band].any():
        raise InputError(f"{source}: every value in the selected band is marked invalid")


def _mode_table(summary: dict) -> str:
    """The roots (step 1) and, beside them, the undamped frequencies of the written M, K: the
    two agree for a full-order fit and may not for a reduced-order one (a free test), whose
    M, K are step 2's fit to those roots. Rigid-body modes (``R1``...) head the table.

    Row by row only where the written M, K have one elastic mode per root and no negative
    eigenvalue: otherwise both are ascending lists of different things (the QA's record gave
    -12408.78 and -8.42 Hz beside roots at 4.3 and 6.2 Hz, and every row after them one mode
    apart), and the M, K frequencies follow the table on their own line, a negative
    eigenvalue of (K, M) as the omega^2 it is, not as a frequency.
    """
    freqs = summary.get("natural_freq_hz", [])
    zetas = summary.get("damping_ratio", [])
    # A free-free model's rigid-body modes come first in eig(K, M) (at 0 Hz) and have no
    # root among the modes: they get their own rows, and the modes pair with the rest.
    n_rigid = int(summary.get("n_rigid_body_modes") or 0)
    elastic, negative = _undamped_split(summary.get("undamped_freq_hz", []), n_rigid)
    # M not positive definite: every value is null, and the column shows "-" (docs/formats.md).
    side = all(math.isnan(f) for f in elastic) or (not negative and len(elastic) == len(freqs))
    mk = (lambda text: f"  {text:>12}") if side else (lambda text: "")
    lines = [f"{'mode':>4}  {'f_n [Hz]':>12}  {'damping [%]':>11}" + mk("M,K f [Hz]")]
    lines += [f"{f'R{k}':>4}  {'rigid body':>12}  {'-':>11}" + mk(_fmt(0.0, 1.0, ".4f"))
              for k in range(1, n_rigid + 1)]
    for k, (f_n, zeta) in enumerate(zip(freqs, zetas)):
        f_mk = elastic[k] if k < len(elastic) else None
        lines.append(f"{k + 1:>4}  {_fmt(f_n, 1.0, '.4f'):>12}  {_fmt(zeta, 100.0, '.3f'):>11}"
                     + mk(_fmt(f_mk, 1.0, ".4f")))
    if not side:
        lines.append(f"M,K f [Hz]: the written M, K's undamped frequencies, {len(elastic)} for {len(freqs)} "
                     "roots, so not paired with them row by row: " + ", ".join(f"{f:.4f}" for f in elastic))
    if negative:
        omega2 = ", ".join(f"{-(2 * math.pi * f) ** 2:.4g}" for f in negative)
        lines.append(f"(K, M) also has {len(negative)} negative eigenvalue(s), omega^2 = {omega2} (rad/s)^2: "
                     "K is not positive semi-definite, and these are motions that diverge, not frequencies")
    return "\n".join(lines)


def _undamped_split(undamped: list, n_rigid: int) -> tuple[list[float], list[float]]:
    """``undamped_freq_hz`` (signed, ascending; null where undetermined) without its
    ``n_rigid`` rigid-body zeros: the elastic frequencies (NaN for null) and the negative
    ones (a negative eigenvalue of (K, M), written as ``-sqrt(-omega^2) / 2 pi``)."""
    values = [math.nan if v is None else float(v) for v in undamped]
    for _ in range(n_rigid):
        if 0.0 in values:
            values.remove(0.0)
    return [v for v in values if not v < 0], [v for v in values if v < 0]


def _fmt(value: Any, scale: float, spec: str) -> str:
    # Undetermined values arrive as None (JSON null) or NaN; show them as a dash.
    if value is None or not math.isfinite(float(value)):
        return "-"
    return format(scale * float(value), spec)
