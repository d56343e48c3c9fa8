"""The layers are one-way by folder (docs/architecture.md): ``components`` at the bottom, ``fmus``
and ``hardware`` on it, ``seafmu/`` (CLI, master, build, export, identification) on top.

Every .py file under components/, fmus/ and hardware/ is parsed (imports inside functions and
``if TYPE_CHECKING:`` blocks included): none imports a higher layer, and none imports its own
package by the absolute name ``seafmu.<layer>`` (they import relatively, so the same files work as
``seafmu.components`` and under an FMU's per-build bundle name).

A function over 80 lines anywhere in the package (components/, fmus/, hardware/, seafmu/) says
why in a comment ``# Long because ...`` or ``# Over 80 lines: ...`` right under its signature (or
docstring), or in its docstring. ``python tests/test_layers.py`` lists every long function of the repository.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LOWER = ("components", "fmus", "hardware")
# what each lower layer may import from seafmu's own packages
ALLOWED: dict[str, set[str]] = {
    "components": {"components"},
    "fmus": {"components", "fmus"},
    "hardware": {"components", "fmus", "hardware"},
}


def _imports(path: Path) -> list[tuple[int, str, int]]:
    """(line, module, level) of every import in the file; ``from . import x`` gives module ``x``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name, 0) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.module:
                found.append((node.lineno, node.module, node.level))
            else:
                found += [(node.lineno, a.name, node.level) for a in node.names]
    return found


def _target(layer: str, rel: Path, module: str, level: int) -> str | None:
    """The seafmu layer an import reaches ("components", "fmus", "hardware", "seafmu" for the top
    modules), or None for a third-party or standard-library module."""
    if level == 0:
        parts = module.split(".")
        if parts[0] != "seafmu":
            return None
        return parts[1] if len(parts) > 1 and parts[1] in LOWER else "seafmu"
    # relative: resolve against the file's package; the layer folders sit in one root package
    # (``seafmu`` when installed, the bundle's name inside an FMU)
    package = ["<root>", layer, *rel.parent.parts]
    if level > len(package):
        return "seafmu"  # above the root package
    base = package[: len(package) - (level - 1)]
    if len(base) > 1:
        return base[1]
    first = module.split(".")[0]
    return first if first in LOWER else "seafmu"


def _files(layer: str) -> list[Path]:
    return sorted(p for p in (REPO / layer).rglob("*.py") if "__pycache__" not in p.parts)


@pytest.mark.parametrize("layer", LOWER)
def test_no_import_of_a_higher_layer(layer: str) -> None:
    files = _files(layer)
    assert files
    bad = []
    for path in files:
        rel = path.relative_to(REPO / layer)
        for line, module, level in _imports(path):
            target = _target(layer, rel, module, level)
            if target is not None and target not in ALLOWED[layer]:
                bad.append(f"{path.relative_to(REPO)}:{line}: {'.' * level}{module} ({target} layer)")
    assert not bad, f"{layer} imports a higher layer:\n" + "\n".join(bad)


@pytest.mark.parametrize("layer", LOWER)
def test_lower_layers_import_each_other_relatively(layer: str) -> None:
    bad = [f"{path.relative_to(REPO)}:{line}: {module}"
           for path in _files(layer) for line, module, level in _imports(path)
           if level == 0 and module.split(".")[0] == "seafmu"]
    assert not bad, f"{layer} imports seafmu by its absolute name (relative imports only):\n" + "\n".join(bad)


def test_the_checker_sees_imports_inside_functions(tmp_path: Path) -> None:
    f = tmp_path / "x.py"
    f.write_text("def f():\n    from seafmu.scenario import load_scenario\n    from ..fmus import _slave\n"
                 "    from ... import master\n")
    found = _imports(f)
    assert [(m, lv) for _, m, lv in found] == [("seafmu.scenario", 0), ("fmus", 2), ("master", 3)]
    rel = Path("x.py")
    assert [_target("hardware", rel, m, lv) for _, m, lv in found] == ["seafmu", "fmus", "seafmu"]
    assert _target("hardware", Path("sub/y.py"), "link", 2) == "hardware"
    assert _target("components", rel, "numpy", 0) is None


# -- long functions say why -----------------------------------------------------------------------
LONG = 80  # lines, def to last line
LONG_SCOPE = ("components", "fmus", "hardware", "seafmu")
WHY = ("long because", "over 80 lines")


def _explained(node: ast.FunctionDef | ast.AsyncFunctionDef, lines: list[str]) -> bool:
    """The docstring, or a comment between the signature and the first statement after the
    docstring, says why the function is long."""
    doc = (ast.get_docstring(node) or "").lower()
    if any(w in doc for w in WHY):
        return True
    body = node.body[1:] if ast.get_docstring(node) is not None and len(node.body) > 1 else node.body
    head = lines[node.lineno - 1 : body[0].lineno - 1]
    return any(line.strip().lower().startswith(tuple("# " + w for w in WHY)) for line in head)


def long_functions(paths: list[Path]) -> list[tuple[Path, str, int, bool]]:
    """(file, function, length in lines, explained) of every function longer than LONG lines."""
    found = []
    for path in paths:
        text = path.read_text()
        lines = text.splitlines()
        for node in ast.walk(ast.parse(text, filename=str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                if length > LONG:
                    found.append((path, node.name, length, _explained(node, lines)))
    return found


def _scope_files() -> list[Path]:
    files: list[Path] = []
    for entry in LONG_SCOPE:
        files += _files(entry) if (REPO / entry).is_dir() else [REPO / entry]
    return files


def test_long_functions_say_why() -> None:
    bad = [f"{p.relative_to(REPO)}: {name} ({n} lines)" for p, name, n, ok in long_functions(_scope_files())
           if not ok]
    assert not bad, f"functions over {LONG} lines without '# Long because ...':\n" + "\n".join(bad)


def test_the_long_function_checker_finds_them(tmp_path: Path) -> None:
    body = "".join(f"    x{i} = {i}\n" for i in range(LONG))
    f = tmp_path / "m.py"
    f.write_text(f"def silent():\n{body}\n"
                 f"def commented(a,\n              b):\n    # Long because a table.\n{body}\n"
                 f"def documented():\n    \"\"\"Long because a table.\"\"\"\n{body}\n"
                 f"def after_doc():\n    \"\"\"A table.\"\"\"\n    # long because one value a line\n{body}\n"
                 "def short():\n    return 1\n")
    found = {name: ok for _, name, _, ok in long_functions([f])}
    assert found == {"silent": False, "commented": True, "documented": True, "after_doc": True}


if __name__ == "__main__":  # every long function of the repository, explained or not
    every = sorted(p for p in REPO.rglob("*.py") if not {".venv", "__pycache__", "build"} & set(p.parts))
    for p, name, n, ok in long_functions(every):
        print(f"{'ok ' if ok else 'NO '} {n:4d}  {p.relative_to(REPO)}:{name}")
