"""Which coherence functions of a UFF file become the FRF file's ``coherence``.

The FRF file holds, per (output, input) pair, the coherence of the output: the ordinary
coherence with one input, the output's **multiple** coherence with several (docs/formats.md).
A UFF file may hold either kind (function type 6 ordinary, 26 multiple), both, one multiple
coherence per output (reference node 0, or one reference) or one per pair (what ssidlab
writes: type 6, since pyuff cannot write 26, with ID line 1 saying "multiple coherence").
:func:`select_coherence` picks one function per pair by these rules (reasons in
``docs/exchange.md``):

* a multiple coherence wins over an ordinary one for the same pair;
* an output's single multiple coherence is that output's for every input; several are each
  their pair's;
* an ordinary coherence is used with one input only: with several it is not the multiple
  coherence (their sum is, only for uncorrelated inputs, which the file does not tell), so it
  is left out with a warning;
* two functions of one kind for one pair cannot be placed: the coherence is left out with a
  warning, the FRFs are read without it.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

from .uff import UFFWarning

__all__ = ["OUTPUT_ONLY", "is_multiple", "select_coherence"]

#: The reference label of a coherence that belongs to its output alone (reference node 0).
OUTPUT_ONLY = ""


def is_multiple(d: dict, multiple_type: int) -> bool:
    """Whether a coherence dataset 58 is a multiple coherence: function type 26, or type 6
    with ID line 1 saying so (ssidlab's writer; pyuff writes no type 26), or without a
    reference node (an ordinary coherence is one output's with one input: it has one)."""
    return (d.get("func_type") == multiple_type
            or "multiple coherence" in str(d.get("id1") or "").lower()
            or int(d.get("ref_node") or 0) == 0)


def select_coherence(src: str, cohs: list[Any], inputs: list[str]) -> list[Any]:
    """One coherence function per (output, input) pair, by the rules of the module.

    Parameters
    ----------
    src : str
        The file, for the warnings.
    cohs : list of uff_read._Function
        Coherence functions (``kind`` "coherence"), each with ``multiple`` set and ``ref``
        :data:`OUTPUT_ONLY` for an output's multiple coherence without a reference.
    inputs : list of str
        The input labels of the FRFs, in the order to fill an output's coherence in.

    Returns
    -------
    list
        The functions to store, ``ref`` set to an input for each; empty when none can be.
    """
    n_in = len(dict.fromkeys(inputs))
    chosen: list[Any] = []
    left_out: list[Any] = []
    by_output: dict[str, list[Any]] = {}
    for c in cohs:
        by_output.setdefault(c.rsp, []).append(c)
    for group in by_output.values():
        multiple = [c for c in group if c.multiple]
        ordinary = [c for c in group if not c.multiple]
        if len(multiple) == 1:
            # The output's multiple coherence, whichever reference it was written against.
            chosen += [dataclasses.replace(multiple[0], ref=ref) for ref in dict.fromkeys(inputs)]
            continue
        chosen += multiple
        covered = {c.ref for c in multiple}
        rest = [c for c in ordinary if c.ref not in covered]
        if n_in == 1:
            chosen += rest  # with one input the ordinary coherence is the multiple one
        else:
            left_out += rest
    if left_out:
        c = left_out[0]
        warnings.warn(f"{src}: {len(left_out)} ordinary coherence function(s) (function type "
                      f"6, e.g. dataset {c.index + 1}, {c.rsp}/{c.ref}) not read: with {n_in} "
                      "inputs the FRF file holds each output's multiple coherence, which the "
                      "ordinary ones do not give (their sum is it only for uncorrelated "
                      "inputs)", UFFWarning, stacklevel=3)
    seen: dict[tuple[str, str], Any] = {}
    for c in chosen:
        other = seen.setdefault((c.rsp, c.ref), c)
        if other is not c or c.ref == OUTPUT_ONLY:
            what = "the multiple coherence of" if c.multiple else "the coherence"
            if other is not c:
                found = f"datasets {other.index + 1} and {c.index + 1} are both {what} {c.rsp}/{c.ref}"
            else:
                found = (f"dataset {c.index + 1} is {what} {c.rsp} without a reference, beside "
                         "others of that output with one")
            warnings.warn(f"{src}: {found}; coherence not read, as the file does not say which "
                          "holds (the FRFs were read without it)", UFFWarning, stacklevel=3)
            return []
    return chosen
