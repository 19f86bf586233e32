"""Import arrows run downward: command line -> composers -> configuration and model library -> stages ->
frames and readers -> utilities. A module may import from its own layer or a lower one, never a higher one,
and no two modules import each other (directly or round a loop). Imports under ``if TYPE_CHECKING:`` are
annotations only and are not counted; imports inside functions are."""
import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parent.parent / "pcdet"

# lowest first; a module is placed by the longest dotted prefix listed (``image.cli`` before ``image``)
LAYERS = [
    ("utilities", ["errors", "params", "_o3d", "resources", "align", "camera", "cloud", "pairs", "lrf", "render",
                   "sensor", "metrics", "trajectory", "io", "colour", "blas", "graph",
                   "residuals", "grid"]),
    ("frames and readers", ["frame", "datasets"]),
    ("stages", ["preprocess", "keypoints", "features", "matching", "grouping", "refine", "verify", "look_alikes",
                "global_verify", "odometry", "scene", "model_views", "model", "prepared_model", "image"]),
    ("configuration and library", ["config", "model_cache", "library"]),
    ("composers", ["detector", "register", "tracking", "runner", "executors", "evaluate", "synth", "viz",
                   "diagnose", "odometry_run"]),
    ("command line", ["cli", "console", "image.cli", "__init__"]),
]


def _modules() -> dict[str, Path]:
    out = {}
    for p in sorted(PKG.rglob("*.py")):
        parts = list(p.relative_to(PKG).with_suffix("").parts)
        if parts[-1] == "__init__" and len(parts) > 1:
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def _layer(name: str) -> int:
    best, rank = -1, None
    for i, (_, prefixes) in enumerate(LAYERS):
        for pre in prefixes:
            if (name == pre or name.startswith(pre + ".")) and len(pre) > best:
                best, rank = len(pre), i
    assert rank is not None, f"pcdet.{name} is in no layer: add it to LAYERS"
    return rank


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """pcdet modules that ``name`` imports at run time."""
    tree = ast.parse(path.read_text())
    typing_only = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            typing_only |= {id(n) for n in ast.walk(node)}
    pkg = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found = set()
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[: len(pkg) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            elif node.module and node.module.startswith("pcdet"):
                mod = node.module[len("pcdet."):] if node.module != "pcdet" else ""
            else:
                continue
            for alias in node.names:  # "from . import x" may name a submodule
                sub = f"{mod}.{alias.name}" if mod else alias.name
                found.add(sub if sub in known else mod)
        elif isinstance(node, ast.Import):
            found |= {a.name[len("pcdet."):] for a in node.names if a.name.startswith("pcdet.")}
    return {m for m in found if m in known and m != name}


def _graph():
    mods = _modules()
    known = set(mods)
    return {name: _imports(name, path, known) for name, path in mods.items()}


def test_every_import_points_to_the_same_or_a_lower_layer():
    upward = [f"pcdet.{a} ({LAYERS[_layer(a)][0]}) imports pcdet.{b} ({LAYERS[_layer(b)][0]})"
              for a, deps in _graph().items() if a for b in deps if b and _layer(b) > _layer(a)]
    assert not upward, "\n".join(upward)


def test_no_import_cycles():
    graph = _graph()
    state: dict[str, int] = {}

    def visit(n, stack):
        state[n] = 1
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                pytest.fail("import cycle: " + " -> ".join(stack[stack.index(m):] + [m]))
            if m not in state:
                visit(m, stack + [m])
        state[n] = 2

    for n in sorted(graph):
        if n not in state:
            visit(n, [n])


def test_no_module_imports_another_modules_private_names():
    bad = []
    for name, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("pcdet")):
                bad += [f"pcdet.{name}: {a.name}" for a in node.names
                        if a.name.startswith("_") and a.name not in ("__version__",) and node.module != "_o3d"
                        # a compiled kernel, by its wrapper
                        and (name, a.name) not in (("graph", "_graph"), ("residuals", "_residuals"), ("grid", "_grid"),
                                                   ("features", "_fpfh"), ("align", "_align"), ("cloud", "_normals"),
                                                   ("lrf", "_lrf"), ("grouping.hough", "_votes"))]
    assert not bad, "\n".join(bad)


def test_options_are_keyword_only_outside_the_command_line():
    """No function or method outside the CLI modules takes more than 6 parameters by position (self and cls
    not counted); options go after ``*``."""
    long = []
    for name, path in _modules().items():
        if name in ("cli", "image.cli"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                pos = [a.arg for a in node.args.posonlyargs + node.args.args if a.arg not in ("self", "cls")]
                if len(pos) > 6:
                    long.append(f"pcdet.{name}.{node.name}: {len(pos)} positional ({', '.join(pos)})")
    assert not long, "\n".join(long)


def test_every_public_module_class_and_function_has_a_docstring():
    missing = []
    for name, path in _modules().items():
        tree = ast.parse(path.read_text())
        if not ast.get_docstring(tree):
            missing.append(f"pcdet.{name}")
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)) and not node.name.startswith("_"):
                if not ast.get_docstring(node):
                    missing.append(f"pcdet.{name}.{node.name}")
                if isinstance(node, ast.ClassDef):
                    missing += [f"pcdet.{name}.{node.name}.{m.name}" for m in node.body
                                if isinstance(m, ast.FunctionDef) and not m.name.startswith("_")
                                and not ast.get_docstring(m)]
    assert not missing, "\n".join(missing)
