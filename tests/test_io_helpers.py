"""Shared pieces of tests/test_io*.py (no tests here): the one-line error check, dataset surgery."""

from __future__ import annotations

import h5py
import numpy as np


def assert_one_line_error(excinfo, path, *fragments: str) -> None:
    """The message is one line, names the file and contains each fragment."""
    message = str(excinfo.value)
    assert "\n" not in message and "\r" not in message
    assert message.startswith(str(path))
    for fragment in fragments:
        assert fragment in message, message


def replace_dataset(f: h5py.File, name: str, data, **kwargs) -> None:
    del f[name]
    f.create_dataset(name, data=data, **kwargs)


# Corruptions: each returns a function that damages an open h5py file in place.


def nan_at(name, value=np.nan):
    def corrupt(f):
        a = f[name][()]
        a.flat[7] = value
        f[name][...] = a

    return corrupt


def set_attr(key, value):
    def corrupt(f):
        f.attrs[key] = value

    return corrupt


def delete(name):
    def corrupt(f):
        if name in f:
            del f[name]
        else:
            del f.attrs[name]

    return corrupt


def labels_to(name, labels):
    """Set string dataset ``name`` to ``labels``, creating it if absent."""

    def corrupt(f):
        if name in f:
            del f[name]
        f.create_dataset(name, data=np.array(labels, dtype=object), dtype=h5py.string_dtype())

    return corrupt


def replace_values(name, make, **kwargs):
    """Replace dataset ``name`` by ``make(old_values)``."""

    def corrupt(f):
        replace_dataset(f, name, make(f[name][()]), **kwargs)

    return corrupt
