"""``ssidlab compare``: two FRF files of one structure - do they agree within their noise?

    ssidlab compare A.h5 B.h5 [--json OUT.json] [--quiet]

The linearity check (the same test at two force levels) and the repeatability check (the
same test on another day, after a re-mount) of a modal test (``ssid.frf_compare``). Each FRF
of ``A`` is compared with the same output / input FRF of ``B`` over the lines both measured:
the gain ``rho`` in ``H_A ~ rho H_B``, FRAC, and what the gain leaves in units of the stated
noise. The interface reactions (load cells) both files hold are compared alike. An FRF whose
gain is off 1 beyond the calibration tolerance and its noise, or whose shape differs beyond
the noise, is listed; outputs, inputs or reactions only one file holds are named in a warning.
Exit 0 when the comparison was made (whatever it found; the JSON's ``agree`` says), 2 on bad
input.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

__all__ = ["add_compare_subcommand"]

HELP = ("Compare two FRF files of one structure (linearity between force levels, repeatability "
        "between runs): gain, FRAC and residual against the stated noise.")


def add_compare_subcommand(sub: Any) -> argparse.ArgumentParser:
    """Add the ``compare`` subparser to ``sub`` (an argparse subparsers action); returns it."""
    p = sub.add_parser("compare", prog="ssidlab compare", help=HELP, description=HELP, allow_abbrev=False)
    p.add_argument("a", metavar="A.h5", help="FRF file (ssidlab-frf, e.g. a run file)")
    p.add_argument("b", metavar="B.h5", help="FRF file of the same structure to compare it with")
    p.add_argument("--json", metavar="OUT.json", help="every FRF's comparison and the verdict as JSON")
    p.add_argument("--quiet", action="store_true", help="only the verdict line")
    p.set_defaults(run=run_compare)
    return p


def _row(c) -> str:
    resid = (f", residual {c.residual_ratio:.3g} x noise, {c.relative_residual:.2g} of the FRF"
             if np.isfinite(c.residual_ratio) else "")
    why = [w for w, bad in (("gain", not c.gain_ok), ("shape", not c.shape_ok)) if bad]
    return c.describe() + resid + (f": {' and '.join(why)} differ" if why else "")


def run_compare(args: argparse.Namespace) -> int:
    from ssid.frf_compare import MIN_COMMON_LINES, compare_frfs
    from ssid.io import read_measured_frf
    from ssidlab.argtypes import check_output_paths, write_json

    check_output_paths([args.a, args.b], [args.json])
    a, b = read_measured_frf(args.a), read_measured_frf(args.b)
    cmp = compare_frfs(a, b)
    n, bad = cmp.n_compared(), cmp.disagreeing()
    f = cmp.freq_hz
    if cmp.n_unmatched:
        # Two grids that differ inside the band both cover: the verdict is over fewer lines
        # than the records hold, which the user must know before trusting it.
        print(f"warning: {cmp.n_unmatched} lines of the band both files cover have no line in the "
              f"other file (different line grids?); compared over the {f.size} that match",
              file=sys.stderr)
    ra, rb = _reactions(a), _reactions(b)
    only = {f"{kind} only in {src}": [x for x in mine if x not in theirs]
            for kind, src, mine, theirs in (("outputs", args.a, a.outputs, b.outputs),
                                            ("outputs", args.b, b.outputs, a.outputs),
                                            ("inputs", args.a, a.inputs, b.inputs),
                                            ("inputs", args.b, b.inputs, a.inputs),
                                            ("reactions", args.a, ra, rb),
                                            ("reactions", args.b, rb, ra))}
    only = {what: labels for what, labels in only.items() if labels}
    for what, labels in only.items():
        # Not compared, so not in the verdict: "all agree" must not cover a channel that one
        # file lacks (renamed, or dropped from one test).
        print(f"warning: {what}, not compared: {', '.join(labels)}", file=sys.stderr)
    # The reactions (load cells) are FRFs like the accelerances, compared and counted apart:
    # a load cell off its calibration shows in its reactions only.
    n_r, bad_r = cmp.n_reactions_compared(), cmp.disagreeing_reactions()
    skipped = len(cmp.outputs) * len(cmp.inputs) - n
    skipped_r = len(cmp.reactions) * len(cmp.inputs) - n_r
    for k, what in ((skipped, "FRF(s)"), (skipped_r, "reaction FRF(s)")):
        if k:
            # Not in the verdict's count: "all 30 agree" of 32 would read as all of them.
            print(f"warning: {k} {what} have fewer than {MIN_COMMON_LINES} valid values in common "
                  "and are not compared", file=sys.stderr)
    if not args.quiet:
        n_react = len(cmp.reactions)
        react = f", {n_react} reaction{'s' if n_react > 1 else ''}" if n_react else ""
        print(f"{args.a} against {args.b}: {f.size} common lines ({f[0]:.4g}-{f[-1]:.4g} Hz), "
              f"{len(cmp.outputs)} outputs{react} x {len(cmp.inputs)} inputs")
        for kind, rows in (("", bad), ("reaction ", bad_r)):
            for o, i, c in rows:
                print(f"  {kind}{o} / {i}: "
                      + ("zero at every line in one file (a dead channel?)" if c.dead else _row(c)))
    over = f"over {f.size} common lines"
    if not (bad or bad_r):
        counted = f"{n} FRFs" + (f" and {n_r} reaction FRFs" if n_r else "")
        verdict = f"all {counted} agree within their noise and the calibration tolerance {over}"
    else:
        counted = f"{len(bad)} of {n} FRFs" + (f" and {len(bad_r)} of {n_r} reaction FRFs" if n_r else "")
        verdict = f"{counted} differ beyond their noise or the calibration tolerance {over}"
    print(verdict)
    if args.json:
        write_json(args.json, {
            "a": args.a, "b": args.b, "n_lines": int(f.size), "n_unmatched": cmp.n_unmatched,
            "not_compared": only,
            "n_compared": n, "n_differ": len(bad),
            "n_reactions_compared": n_r, "n_reactions_differ": len(bad_r),
            "agree": not (bad or bad_r), "verdict": verdict,
            "frfs": [{"output": o, "input": i, **c.to_json_dict()}
                     for o, row in zip(cmp.outputs, cmp.curves) for i, c in zip(cmp.inputs, row) if c is not None],
            "reactions": [{"reaction": r, "input": i, **c.to_json_dict()}
                          for r, row in zip(cmp.reactions, cmp.reaction_curves)
                          for i, c in zip(cmp.inputs, row) if c is not None]})
    return 0


def _reactions(frf) -> list[str]:
    """Reaction labels a record holds (none without ``H_reaction``)."""
    return list(frf.reactions or []) if frf.H_reaction is not None else []
