"""The replication's Target, row by row: for every figure of the report the bench compares
with, the report's figure, ours and whether ours is no worse (bench/replicate_report.py
prints this table first). Each verdict is computed from the numbers of the run that wrote the
document, never written by hand."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from report_truth import fmt


@dataclass(frozen=True)
class TargetRow:
    """One compared figure: where it is, the report's, ours and the verdict."""

    section: str
    row: str
    report: str
    ours: str
    verdict: str


def no_worse(ours: tuple[float, float, int], report: tuple[float, float],
             report_missed: int = 0, report_note: str = "") -> str:
    """Verdict on a (frequency %, damping %, targets missed) figure against the report's
    (frequency %, damping %): "yes" when ours misses no more targets and neither error is
    larger, else what is worse. ``report_note`` qualifies the report's miss count."""
    f, d, miss = ours
    if not np.isfinite(f):
        return "no: no model"
    worse = []
    if miss > report_missed:
        worse.append(f"{miss} target(s) missed (the report: {report_missed}{report_note})")
    worse += [f"{name} error larger" for name, a, b in (("frequency", f, report[0]),
                                                       ("damping", d, report[1])) if a > b]
    return "yes" if not worse else "no: " + "; ".join(worse)


def no_fewer(ours: int, report: int, what: str) -> str:
    """Verdict on a count of targets held: "yes" when ours holds no fewer."""
    return "yes" if ours >= report else f"no: {report - ours} fewer {what}"


def figure(errs: tuple[float, float, int]) -> str:
    """A (frequency %, damping %, missed) figure as the tables print it, or "no model"."""
    return " ".join(fmt(*errs).split()) if np.isfinite(errs[0]) else "no model"


def status_table(rows: list[TargetRow]) -> str:
    """The markdown section that leads docs/replication.md."""
    met = sum(r.verdict == "yes" for r in rows)
    failed = sum(r.verdict.startswith("the report had none") for r in rows)
    out = ["## Target, row by row",
           "",
           "The issue's Target: at every row, our error no worse than the report's; where the "
           "report failed, what we achieve. Each row below is one figure the sections that "
           "follow compare with the report's, and `ours` is the cell named in it (for sections "
           "2 and 3 the band search's choice, `ssid.band_select.identify_mck_band_select`, made "
           "from the data alone; in section 3 without the modal model a residual pair completes, "
           "as its notes say; a figure is frequency / damping max |% error| over the target "
           "modes, and the targets missed). `no worse`: ours misses no more targets and neither "
           "error is larger (or, for counts, ours holds no fewer). Why a row falls short is in "
           "its section's notes.",
           "",
           f"**{met} of {len(rows) - failed} rows no worse than the report's; "
           f"{failed} where the report had no solution.**",
           "",
           "| section | row | report | ours | no worse |",
           "|---|---|---|---|---|"]
    out += [f"| {r.section} | {r.row} | {r.report} | {r.ours} | {r.verdict} |" for r in rows]
    return "\n".join(out) + "\n"
