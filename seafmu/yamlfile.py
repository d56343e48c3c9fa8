"""Reading the project's YAML input files (scenarios, trials) with one-line errors.

Both loaders need the same things: a top-level mapping, a clear line for unreadable or non-UTF-8
files and bad YAML, no silently overridden duplicate keys, and pydantic's first error as
``field.path: what is wrong (got value)``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError


class _UniqueKeyLoader(yaml.SafeLoader):
    """YAML silently keeps the last of two equal keys; in an input file that hides a mistake."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                where = f"duplicate key '{key}' (line {key_node.start_mark.line + 1})"
                raise yaml.constructor.ConstructorError(None, None, where, key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def read_mapping(path: Path, what: str, error: type[ValueError]) -> dict[str, Any]:
    """The file's top-level mapping; ``error`` (one line naming the file) for anything else."""
    try:
        doc = yaml.load(path.read_text(encoding="utf-8"), Loader=_UniqueKeyLoader)
    except yaml.YAMLError as exc:
        first = str(exc).replace("\n", " ").strip()
        if isinstance(exc, yaml.constructor.ConstructorError) and exc.problem:
            first = exc.problem
        raise error(f"{path}: not valid YAML ({first})") from None
    except UnicodeDecodeError:
        raise error(f"{path}: not UTF-8 text") from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not isinstance(doc, dict):
        raise error(f"{path}: expected a mapping of {what} fields at the top level")
    return doc


def validation_message(exc: ValidationError) -> str:
    """Pydantic's first error as one line: ``field.path: what is wrong (got value)``."""
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
    plain = {"extra_forbidden": "unknown field", "missing": "required field is missing"}
    msg = plain.get(err["type"], err["msg"])
    got = "" if err["type"] in ("missing", "extra_forbidden") else f" (got {err.get('input')!r})"
    return f"{loc}: {msg}{got}"
