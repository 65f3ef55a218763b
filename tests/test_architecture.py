"""The tree shows the wings, and each wing depends only on those below it
(docs/architecture.md): every import inside ``bgc`` goes down the layers, and
the public face is ``bgc`` itself."""

from __future__ import annotations

import ast

from conftest import ROOT

#: The wings from the bottom up; a module may import its own wing and those before it.
LAYERS = (
    {"errors", "kinds", "ir", "arguments", "events"},
    {"model.protocol"},
    {"filters"},
    {"model"},
    {"data"},
    {"compiler"},
    {"diagnosis", "analysis"},
    {"output"},
    {"pipeline", "view"},
    {"api"},
    {"service", "experiment"},
    {"cli"},
    {"__init__", "__main__"},
)
#: Wings side by side in one layer that must not import each other.
APART = {("diagnosis", "analysis"), ("analysis", "diagnosis"), ("service", "experiment"), ("experiment", "service")}


def _wing(module: str) -> str:
    parts = module.split(".")[1:]
    if not parts:
        return "__init__"
    if parts[:2] == ["model", "protocol"]:
        return "model.protocol"
    return parts[0]


def _imports():
    """(importing module, imported module) of every import of bgc inside bgc."""
    for path in (ROOT / "bgc").rglob("*.py"):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        package = parts[:-1] if parts[-1] != "__init__" else parts[:-1]
        module = ".".join(parts if parts[-1] != "__init__" else parts[:-1])
        if parts[-1] == "__init__":
            package = parts[:-1]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package[:len(package) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                names = [f"{target}.{a.name}" if target == "bgc" else target for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for name in names:
                if name == "bgc" or name.startswith("bgc."):
                    yield module, name


def test_every_import_goes_down_the_layers():
    layer = {wing: i for i, wings in enumerate(LAYERS) for wing in wings}
    upward = []
    for module, target in _imports():
        a, b = _wing(module), _wing(target)
        if b == "__version__":
            continue
        assert a in layer and b in layer, f"{module} or {target}: a wing docs/architecture.md does not place"
        if a != b and (layer[b] > layer[a] or (a, b) in APART):
            upward.append(f"{module} -> {target}")
    assert not upward, "imports against the layers:\n" + "\n".join(sorted(upward))


def test_the_layer_test_sees_an_upward_import():
    """The test above can fail: an import of the CLI from the filters is one it reports."""
    layer = {wing: i for i, wings in enumerate(LAYERS) for wing in wings}
    assert layer[_wing("bgc.cli.main")] > layer[_wing("bgc.filters.particle")]
    assert ("diagnosis", "analysis") in APART
    assert sum(1 for _ in _imports()) > 200


#: The longest a function of the online loop (bgc/diagnosis) may be, in lines with its docstring.
LONGEST = 60


def _functions(folder):
    """(lines, 'path:name') of every function and method below ``folder``."""
    for path in sorted(folder.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield node.end_lineno - node.lineno + 1, f"{path.relative_to(ROOT)}:{node.name}"


def test_the_functions_of_the_loop_are_short():
    """Every function of the diagnosis wing is under LONGEST lines: the loop
    reads as steps, each a function one can hold in mind."""
    found = list(_functions(ROOT / "bgc" / "diagnosis"))
    assert len(found) > 100
    long = sorted((n, where) for n, where in found if n >= LONGEST)
    assert not long, f"functions of the loop of {LONGEST} lines or more (split them): {long}"
