"""DOF labels <-> node number and direction, as UFF, Nastran DMIG and OP4 need them.

ssidlab treats DOF labels as opaque strings, but the exchange formats address a DOF by a node
(grid) number and a direction, so labels must follow the form ``"<node><sign><direction>"``:
``"4+Z"``, ``"17-RX"``, or a bare ``"9"`` for a scalar point. Directions are numbered as in UFF
and Nastran: ``X, Y, Z, RX, RY, RZ = 1 .. 6``; 0 is a scalar point. The form is strict
(upper-case direction, no leading zeros, no blanks) so that a label comes back unchanged after
a round trip through a file that only stores numbers.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from ssid.errors import InputError

__all__ = [
    "DIRECTIONS",
    "MAX_NODE",
    "format_dof_label",
    "labels_to_node_dirs",
    "parse_dof_label",
]

#: Direction names by code 1 .. 6 (code 0 is a scalar point).
DIRECTIONS = ("X", "Y", "Z", "RX", "RY", "RZ")
#: Largest node number: UFF writes nodes in I10 fields, Nastran grid IDs are 32-bit.
MAX_NODE = 2**31 - 1

_LABEL = re.compile(r"([1-9][0-9]*)(?:([+-])(X|Y|Z|RX|RY|RZ))?")
_FORM = "'<node><+|-><X|Y|Z|RX|RY|RZ>' such as '4+Z' or '17-RX', or '<node>' for a scalar point"


def parse_dof_label(label: str) -> tuple[int, int]:
    """Node number and signed direction code of a DOF label.

    Parameters
    ----------
    label : str
        ``"4+Z"`` -> ``(4, 3)``, ``"17-RX"`` -> ``(17, -4)``, ``"9"`` -> ``(9, 0)``.

    Returns
    -------
    (int, int)
        Node >= 1 and direction in -6 .. 6 (0: scalar point).

    Raises
    ------
    ValueError
        The label does not have the node+direction form.
    """
    m = _LABEL.fullmatch(label) if isinstance(label, str) else None
    if m is None:
        raise ValueError(f"DOF label {label!r} is not of the form {_FORM}")
    node = int(m.group(1))
    if node > MAX_NODE:
        raise ValueError(f"DOF label {label!r}: node number exceeds {MAX_NODE}")
    if m.group(3) is None:
        return node, 0
    code = DIRECTIONS.index(m.group(3)) + 1
    return node, code if m.group(2) == "+" else -code


def format_dof_label(node: int, direction: int) -> str:
    """The DOF label of a node and signed direction code: ``(4, -3)`` -> ``"4-Z"``.

    Raises
    ------
    ValueError
        Node < 1 or direction outside -6 .. 6.
    """
    node, direction = int(node), int(direction)
    if not 1 <= node <= MAX_NODE:
        raise ValueError(f"node number {node} is outside 1 .. {MAX_NODE}")
    if not -6 <= direction <= 6:
        raise ValueError(f"direction code {direction} of node {node} is outside -6 .. 6")
    if direction == 0:
        return str(node)
    return f"{node}{'+' if direction > 0 else '-'}{DIRECTIONS[abs(direction) - 1]}"


def labels_to_node_dirs(
    src: str, labels: Sequence[str], what: str = "DOF", target: str = "this format"
) -> list[tuple[int, int]]:
    """:func:`parse_dof_label` over a list, with a one-line InputError naming ``src``.

    ``what`` names the list in the message (``"output"``, ``"dofs"``), ``target`` the format
    that needs the node+direction form.
    """
    out = []
    for label in labels:
        try:
            out.append(parse_dof_label(label))
        except ValueError as exc:
            raise InputError(f"{src}: {what} {exc}; {target} addresses DOFs by node and "
                             "direction, so labels must have that form") from None
    return out
