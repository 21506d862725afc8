"""The repository's layout (issue 61): what the wheel holds and how the modules import each other.

``jaxrb/`` is what a user imports; ``benchmarks/`` (other engines side by
side, the committed report, the GPU runs) builds on it from a checkout and is
left out of the wheel. The import graphs are read from the source with
:mod:`ast`, so nothing is imported and no peer engine needs to be installed:
every ``import`` counts, the ones inside functions too (a circle through a
lazy import is still a circle).
"""

import ast
import fnmatch
import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
#: Engines that only benchmarks/ may import (the ``peers`` extra, and MuJoCo, also in ``dev``).
PEER_ENGINES = ("brax", "mujoco", "jax2d", "pymunk", "pybullet")


def modules_of(package: str) -> dict:
    """``{dotted name: path}`` of every module of ``package`` (a folder at the root), packages by their ``__init__``."""
    found = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imports_of(path: pathlib.Path, module: str) -> list:
    """What ``path`` (the module ``module``) imports, anywhere in it, as ``(module, name or None)`` pairs:
    ``import a.b`` gives (a.b, None), ``from a import b`` gives (a, b) (b a module or a name in a);
    relative imports are resolved against ``module``."""
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found += [(alias.name, None) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[:len(package) - node.level + 1] + ([node.module] if node.module else []))
            found += [(base, alias.name) for alias in node.names]
    return found


def import_graph(modules: dict) -> dict:
    """``{module: the modules of the same set it imports}``; ``from a import b`` is an edge to a.b where
    that is a module, else to a (a package's ``__init__``); a package's parents are left out, as is
    the module itself."""
    graph = {}
    for module, path in modules.items():
        edges = set()
        for base, name in imports_of(path, module):
            if name is not None and f"{base}.{name}" in modules:
                edges.add(f"{base}.{name}")
            elif base in modules:
                edges.add(base)
        graph[module] = edges - {module}
    return graph


def circles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan's algorithm), as sets."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in sorted(graph[node]):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = set()
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.add(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(component)

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_the_import_graph_of_jaxrb_has_no_circles():
    graph = import_graph(modules_of("jaxrb"))
    assert "jaxrb.bench.contact" in graph["jaxrb.bench.hard_cases.stacks"]  # the walk sees imports
    assert "jaxrb.physics.free_body_adjoint" in graph["jaxrb.physics.plane_penalty_adjoint"]  # from jaxrb import x as ...
    found = [sorted(circle) for circle in circles(graph)]
    assert not found, f"modules that import each other, directly or around a circle: {found}"


def test_the_import_graph_of_benchmarks_has_no_circles():
    graph = import_graph(modules_of("benchmarks"))
    assert "benchmarks.scenes" in graph["benchmarks.peer_gradients"]
    assert "benchmarks.peers" not in graph["benchmarks.peer_gradients"]
    assert not circles(graph), circles(graph)


def test_the_checker_finds_a_circle():
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]
    assert circles({"a": {"b"}, "b": set()}) == []


def test_jaxrb_imports_neither_benchmarks_nor_another_engine():
    """MuJoCo's compiler reads model files (jaxrb.files.mjcf, the ``mjcf`` extra); nothing else imports an engine."""
    for module, path in modules_of("jaxrb").items():
        roots = {base.split(".")[0] for base, _ in imports_of(path, module)}
        allowed = {"mujoco"} if module == "jaxrb.files.mjcf" else set()
        assert "benchmarks" not in roots, module
        assert not roots & (set(PEER_ENGINES) - allowed), (module, roots & set(PEER_ENGINES))


def test_the_wheel_holds_jaxrb_and_not_benchmarks():
    """pyproject's package discovery (setuptools matches each dotted package name against ``include``)."""
    text = (ROOT / "pyproject.toml").read_text()
    block = re.search(r"^\[tool\.setuptools\.packages\.find\]\n(.*?)(?=^\[)", text, re.S | re.M).group(1)
    include = re.findall(r'"([^"]+)"', re.search(r"^include\s*=\s*\[(.*?)\]", block, re.S | re.M).group(1))
    assert "exclude" not in block or "jaxrb" not in re.search(r"^exclude.*$", block, re.M).group(0)
    packages = [name for name, path in {**modules_of("jaxrb"), **modules_of("benchmarks")}.items()
                if path.name == "__init__.py"]
    packed = {name for name in packages if any(fnmatch.fnmatchcase(name, pattern) for pattern in include)}
    assert {"jaxrb", "jaxrb.bench", "jaxrb.physics.collision", "jaxrb.physics.contact"} <= packed
    assert not {name for name in packed if name.split(".")[0] == "benchmarks"}, packed
    assert (ROOT / "benchmarks" / "__main__.py").exists()  # python -m benchmarks
