"""Exceptions that carry a one-line, user-facing message."""


class InputError(ValueError):
    """Bad input: an unreadable or malformed file, NaN/Inf data, shapes or labels that disagree.

    The message is one line that names the file and what is wrong; the command line prints it
    and exits with status 2.
    """


class IdentificationError(RuntimeError):
    """The identification could not produce a result (e.g. too few valid lines for the unknowns)."""
