"""YAML 1.2 numbers for every YAML loader of seafmu (vessel files here, scenario/study/trial files in
``seafmu/yamlfile.py``): PyYAML reads YAML 1.1, where ``010`` is octal 8, ``0x10`` 16, ``0b11`` 3,
``1_0`` 10 and ``1:30`` 90 (sexagesimal) — an input file or ``--set`` value silently becomes another
number. Here only plain decimals are numbers (``010`` is 10, as YAML 1.2 reads it); the rest stay
text, which the field's validation refuses by name. Hand-written because PyYAML has no YAML 1.2
schema and ruamel.yaml's round-trip loader is several times slower than libyaml.
"""

from __future__ import annotations

import re
from typing import Any

import yaml

INT_TAG, FLOAT_TAG = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"
DECIMAL_INT = re.compile(r"[-+]?[0-9]+\Z")
DECIMAL_FLOAT = re.compile(r"(?:[-+]?(?:(?:[0-9]+\.[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?"
                           r"|[0-9]+[eE][-+]?[0-9]+)|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))\Z")


def _construct_int(loader: Any, node: yaml.ScalarNode) -> int:
    text = loader.construct_scalar(node)
    if not DECIMAL_INT.match(text):  # also an explicit !!int 0x10: decimal only
        raise yaml.constructor.ConstructorError(None, None, f"'{text}' is not a decimal integer",
                                                node.start_mark)
    return int(text)  # int("010") is 10: a leading zero is not octal


def _construct_float(loader: Any, node: yaml.ScalarNode) -> float:
    text = loader.construct_scalar(node)
    if not (DECIMAL_FLOAT.match(text) or DECIMAL_INT.match(text)):
        raise yaml.constructor.ConstructorError(None, None, f"'{text}' is not a decimal number",
                                                node.start_mark)
    if text.lower().endswith((".inf", ".nan")):  # float() reads "inf" and "nan", not YAML's ".inf"
        return float(text.replace(".", "", 1))
    return float(text)


def decimal_numbers(loader: type) -> None:
    """Make ``loader`` (a SafeLoader or CSafeLoader subclass: resolvers and constructors are Python
    level for both, so libyaml's speed is kept) read YAML 1.2 numbers: its own copy of the implicit
    resolvers with the int and float ones replaced (the base class's stay as they are)."""
    resolvers: dict[str, list[tuple[str, re.Pattern[str]]]] = {
        first: [(tag, rx) for tag, rx in pairs if tag not in (INT_TAG, FLOAT_TAG)]
        for first, pairs in loader.yaml_implicit_resolvers.items()  # type: ignore[attr-defined]
    }
    for first in "-+0123456789":
        resolvers.setdefault(first, []).insert(0, (INT_TAG, DECIMAL_INT))
    for first in "-+.0123456789":
        resolvers.setdefault(first, []).insert(1 if first != "." else 0, (FLOAT_TAG, DECIMAL_FLOAT))
    loader.yaml_implicit_resolvers = resolvers  # type: ignore[attr-defined]
    loader.add_constructor(INT_TAG, _construct_int)  # type: ignore[attr-defined]
    loader.add_constructor(FLOAT_TAG, _construct_float)  # type: ignore[attr-defined]
