"""Changing some fields of a frozen parameter dataclass by name, as benchmarks and overrides spell them."""

from __future__ import annotations

import math
from dataclasses import fields, replace


def with_changes(params, changes: dict):
    """A copy of the dataclass ``params`` with ``changes`` applied. A name ending in ``_deg`` sets the field of that
    name ending in ``_rad``, given in degrees. Unknown names and values of the wrong type (a number for a switch, a
    fraction for a count) raise ValueError naming the class and the parameter; the class's own checks run on the
    result."""
    cls = type(params).__name__
    kinds = {f.name: type(getattr(params, f.name)) for f in fields(params)}
    out = {}
    for key, value in changes.items():
        name = key
        if key.endswith("_deg") and key[:-4] + "_rad" in kinds:
            name = key[:-4] + "_rad"
        if name not in kinds:
            raise ValueError(f"{cls}: unknown parameter {key!r}; expected one of {sorted(kinds)}")
        kind = kinds[name]
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if not (isinstance(value, bool) if kind is bool else
                number and float(value).is_integer() if kind is int else number):
            expected = {bool: "True or False", int: "an integer"}.get(kind, "a number")
            raise ValueError(f"{cls}: {key}: expected {expected}, got {value!r}")
        if name != key:
            value = math.radians(value)
        out[name] = int(value) if kind is int else float(value) if kind is float else value
    return replace(params, **out)
