"""Reading the project's YAML input files (scenarios, trials) with one-line errors.

Both loaders need the same things: a top-level mapping, a clear line for unreadable or non-UTF-8
files and bad YAML, no silently overridden duplicate keys, and pydantic's first error as
``field.path: what is wrong (got value)``.

Input files are also bounded before they cost anything: the file size is checked before it is
read (``MAX_YAML_BYTES``), the nesting depth while the parser streams its events, before anything
is built (deeply nested flow collections crash libyaml's constructor and exhaust Python's
recursion), and the size the document expands to through aliases afterwards (a "billion laughs"
file of a few lines expands to 10^9 values for every later pass over it).

Numbers are read as YAML 1.2 reads them, not as PyYAML's YAML 1.1 (``components/yaml_numbers.py``,
which the vessel files' loader shares): only plain decimals are numbers (``010`` is 10); ``0x10``,
``0b11``, ``1_0`` and ``1:30`` stay text, which the field's validation then refuses.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from seafmu.components.yaml_numbers import decimal_numbers

if TYPE_CHECKING:  # only named here: the sweep reads its study file before pydantic is imported
    from pydantic import ValidationError

MAX_YAML_BYTES = 1_000_000  # a scenario or trial file is a few kB; 1 MB parses in under a second
MAX_YAML_DEPTH = 64  # nesting of mappings and lists
MAX_YAML_VALUES = 1_000_000  # values after expanding aliases

_Base: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml: about 5x faster

class _UniqueKeyLoader(_Base):  # type: ignore[misc, valid-type]
    """YAML silently keeps the last of two equal keys; in an input file that hides a mistake."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            try:
                duplicate = key in seen
                seen.add(key)
            except TypeError:  # an unhashable key (a list or mapping as key): the constructor says so
                break
            if duplicate:
                where = f"duplicate key '{key}' (line {key_node.start_mark.line + 1})"
                raise yaml.constructor.ConstructorError(None, None, where, key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


decimal_numbers(_UniqueKeyLoader)


def load_value(text: str) -> Any:
    """One YAML value from a command line (``--set x=010``), read as the input files are read."""
    return yaml.load(text, Loader=_UniqueKeyLoader)


class _TooBig(ValueError):
    pass


def _too_deep(mark: Any) -> _TooBig:
    line = mark.line + 1 if mark is not None else "?"
    return _TooBig(f"nested more than {MAX_YAML_DEPTH} levels deep (line {line})")


def _check_depth(text: str) -> None:
    """Stream the parser's events (no objects built) and stop at the first too-deep collection."""
    depth = 0
    starts = (yaml.MappingStartEvent, yaml.SequenceStartEvent)
    ends = (yaml.MappingEndEvent, yaml.SequenceEndEvent)
    try:
        for ev in yaml.parse(text, Loader=_Base):
            if isinstance(ev, starts):
                depth += 1
                if depth > MAX_YAML_DEPTH:
                    raise _too_deep(ev.start_mark)
            elif isinstance(ev, ends):
                depth -= 1
    except yaml.MarkedYAMLError as exc:
        # libyaml 0.2.6 (bundled with PyYAML 6.0.4) has a nesting limit of its own, 1000 levels, and
        # its scanner, reading ahead of the events, can reach it before this count reaches ours
        if "nesting depth" not in (exc.problem or ""):
            raise
        raise _too_deep(exc.problem_mark) from None


def _check_expanded(doc: Any) -> None:
    """Count the values the document holds with aliases expanded; shared nodes are counted once
    per reference, computed once (memo), so the count itself costs only the distinct nodes."""
    sizes: dict[int, int] = {}
    open_: set[int] = set()

    def size(x: Any) -> int:
        if not isinstance(x, dict | list):
            return 1
        key = id(x)
        if key in sizes:
            return sizes[key]
        if key in open_:
            raise _TooBig("an alias refers to its own enclosing node (a recursive structure)")
        open_.add(key)
        items = [*x.keys(), *x.values()] if isinstance(x, dict) else x
        n = 1
        for item in items:
            n += size(item)
            if n > MAX_YAML_VALUES:
                raise _TooBig(f"expands to more than {MAX_YAML_VALUES:,} values (through aliases)")
        open_.discard(key)
        sizes[key] = n
        return n

    size(doc)


def read_mapping(path: Path, what: str, error: type[ValueError],
                 max_bytes: int = MAX_YAML_BYTES) -> dict[str, Any]:
    """The file's top-level mapping; ``error`` (one line naming the file) for anything else."""
    try:
        n = path.stat().st_size
        if n > max_bytes:
            raise error(f"{path}: file is {n / 1e6:.3g} MB; {what} files are limited to "
                        f"{max_bytes / 1e6:g} MB (checked before reading)")
        with open(path, "rb") as fh:  # the size again while reading: the file may be growing
            raw = fh.read(max_bytes + 1)
        if len(raw) > max_bytes:
            raise error(f"{path}: file is larger than {max_bytes / 1e6:g} MB; {what} files are limited "
                        "to that")
        text = raw.decode("utf-8")
        _check_depth(text)
        doc = yaml.load(text, Loader=_UniqueKeyLoader)
        _check_expanded(doc)
    except yaml.YAMLError as exc:
        first = str(exc).replace("\n", " ").strip().replace('in "<unicode string>", ', "at ")  # read as text
        if isinstance(exc, yaml.constructor.ConstructorError) and exc.problem:
            first = exc.problem
        raise error(f"{path}: not valid YAML ({' '.join(first.split())})") from None
    except _TooBig as exc:
        raise error(f"{path}: {exc}") from None
    except UnicodeDecodeError:
        raise error(f"{path}: not UTF-8 text") from None
    except (RecursionError, MemoryError):
        raise error(f"{path}: too complex to read (nesting or size)") from None
    except ValueError as exc:  # e.g. an integer of more than 4300 digits (Python's int-from-text limit)
        if isinstance(exc, error):
            raise
        raise error(f"{path}: not valid YAML ({' '.join(str(exc).split())[:160]})") from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not isinstance(doc, dict):
        raise error(f"{path}: expected a mapping of {what} fields at the top level")
    return doc


def validation_message(exc: ValidationError) -> str:
    """Pydantic's first error as one line: ``field.path: what is wrong (got value)``. An unknown
    field comes first (before any other error), with the missing field it may be a misspelling of
    (``duraton`` for ``duration``: "required field is missing" alone would not say what to fix)."""
    import difflib

    errors = exc.errors()
    unknown = [e for e in errors if e["type"] == "extra_forbidden"]
    err = unknown[0] if unknown else errors[0]
    loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
    plain = {"extra_forbidden": "unknown field", "missing": "required field is missing"}
    msg = plain.get(err["type"], err["msg"]).removeprefix("Value error, ")
    if err["type"] == "extra_forbidden":
        missing = [str(e["loc"][-1]) for e in errors if e["type"] == "missing"
                   and tuple(e["loc"][:-1]) == tuple(err["loc"][:-1])]
        near = difflib.get_close_matches(str(err["loc"][-1]), missing, n=1)
        if near:
            msg += f" (did you mean '{near[0]}'? it is missing)"
    quiet = err["type"] in ("missing", "extra_forbidden") or "(got " in msg
    got = "" if quiet else f" (got {_short(err.get('input'))})"
    return " ".join(f"{loc}: {msg}{got}".split())


def _short(value: Any, limit: int = 80) -> str:
    """repr of the offending value, cut: a 10 kB string is not a one-line message."""
    try:
        text = repr(value)
    except Exception:  # a value whose repr fails still gets its one line
        text = f"<{type(value).__name__}>"
    return text if len(text) <= limit else text[: limit - 3] + "..."
