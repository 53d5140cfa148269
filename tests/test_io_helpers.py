"""Shared pieces of tests/test_io*.py (no tests here): the one-line error check, dataset surgery."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from ssid.errors import InputError


def assert_one_line_error(excinfo, path, *fragments: str) -> None:
    """The message is one line, names the file and contains each fragment."""
    message = str(excinfo.value)
    assert "\n" not in message and "\r" not in message
    assert message.startswith(str(path))
    for fragment in fragments:
        assert fragment in message, message


def assert_corrupted_file_refused(path, write, obj, read, corrupt, fragment: str) -> None:
    """Write ``obj`` to ``path``, damage the file with ``corrupt``, and check that ``read``
    refuses it with a one-line ``InputError`` naming the file and containing ``fragment``."""
    write(path, obj)
    with h5py.File(path, "r+") as f:
        corrupt(f)
    with pytest.raises(InputError) as excinfo:
        read(path)
    assert_one_line_error(excinfo, path, fragment)


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
