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


#: Why the rows that fall short do (static: written from the committed run's tables and the
#: sections' notes, as those notes are).
SHORT_ROWS_NOTES = """**What holds back the rows that fall short** (the committed run; the evidence is in each
section's notes):

- *The data prefer a model that holds the targets worse* (section 2: 10-DOF 1-300 Hz, 12-DOF
  1-300 and 1-551 Hz, 16-DOF 1-300 and 1-551 Hz). Started from the SEREP TAM of the target
  modes, which holds every target exactly, and refined on the same record with the same
  weights, step 1 lets targets go and ends 1.5 to 4e5 times higher in output error than our
  fit (at 10 DOFs, 1-300 Hz, it keeps them, the 559 Hz one to 0.16 %, and ends 2.9 times
  higher): a better search by our criterion would not close these rows.
- *Counting* (section 2: 12-DOF 1-650 Hz, 16-DOF 1-650 and 1-1158 Hz; section 3: 12-DOF
  1-650 Hz). Our bands show the sensors more modes than the model has room for beside its
  targets above the band: a fit holding every mode its band shows misses at least 1, 1, 3
  and 1 targets (the report's rows: 0). The modes in the way (585.5, 754.2, 832.2 Hz) are
  rotation-dominated modes that our closed-box rails show at the Z sensors; the report's six
  between its 300 Hz edge and its 11th target were dominated by X rotation (its section
  6.2.3). Counting is not all, though: with every mode not dominated by Z translation left
  out of the FRFs (`bench/hidden_modes.py`, a diagnostic), the 12-DOF rows at 1-300, 1-650 and
  1-551 Hz still miss one target each (19-30 % off) and the 16-DOF rows below 2300 Hz three
  to five.
- *Which modes the data show most strongly* (section 2: 12- and 16-DOF 1-2300 Hz). Band
  processing finds every target, and the modal model keeps the n strongest modes, some of
  them rotation-dominated (832-1604 Hz) instead of targets; with the FE model's target
  modes kept first (`ssidlab bands --targets`), both rows are no worse than the report's.
- *The report's least squares weighs every line alike* (section 5: the report's two
  partitions). Counting is not what holds this row: the lower half of the split (1-1050 Hz)
  holds 13 modes its 10 sensors see, for 10 pseudo DOFs: room for 10 of its 11 targets and
  the 4 targets above the split, 14 in all; Eq. 3.7's least squares finds 7. With each line's
  equations weighted by omega^p, the same pseudo model finds 9 to 12; the data's choice of p,
  the lowest step-2 FRF error, finds 11, one short of the report's 12 (section 5's notes).

What would close the first two kinds is not known: neither a payload fitted to Table 6.1
(its structure is not given; on a fit of effective sections the 12- and 16-DOF rows still miss
targets, section 2's notes) nor hiding the modes in the way did. The third closes if the
analyst's choice of target modes counts as ours; the fourth with a weighting the data do not
choose (p = -2.5 to -3.5 finds 12).
"""


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
    return "\n".join(out) + "\n\n" + SHORT_ROWS_NOTES
