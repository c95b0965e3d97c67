"""The package's public shape: namespaces by concept, a small top level, no private equinox
attributes and no references to documents outside the repository."""

import importlib
import inspect
import pathlib
import re

import lionjax as lj

THIS = pathlib.Path(__file__).resolve()
ROOT = THIS.parents[1]


def test_namespaces_import_and_top_level_is_small():
    for name in ("twin", "studies", "diagnosis", "paper", "datasets", "solutions", "extend"):
        mod = importlib.import_module(f"lionjax.{name}")
        assert getattr(lj, name) is mod
    # 47: the effects (Offset, Coulomb, PreslidingFriction, Spring, PolynomialPosition,
    # LocalizedPosition) stay together at the top level; anything else new goes into a namespace
    assert len(lj.__all__) <= 47 and len(set(lj.__all__)) == len(lj.__all__)
    for name in lj.__all__:
        assert hasattr(lj, name), name
    # every public top-level attribute is either in __all__ or a namespace
    modules = {n for n, v in vars(lj).items() if inspect.ismodule(v)}
    public = {n for n in vars(lj) if not n.startswith("_")}
    assert public - modules == set(lj.__all__)
    # the everyday entry points are the namespaces' functions
    assert lj.study is lj.studies.study and lj.diagnose is lj.diagnosis.diagnose


def test_batched_signature_is_strategy_objects():
    params = inspect.signature(lj.lion_batched).parameters
    assert len(params) <= 12
    bools = [n for n, p in params.items() if isinstance(p.default, bool)]
    assert bools == ["throw"]


def test_no_private_equinox_attributes_and_no_outside_documents():
    pattern = re.compile(r"\._value\b|_index_to_message|GUIDE")
    hits = []
    for folder in ("lionjax", "notebooks", "benchmarks", "tests"):
        for path in (ROOT / folder).rglob("*"):
            if path.suffix in (".py", ".ipynb", ".md") and path.is_file() and path != THIS:
                for i, line in enumerate(path.read_text().splitlines(), 1):
                    if pattern.search(line):
                        hits.append(f"{path.relative_to(ROOT)}:{i}: {line.strip()}")
    readme = (ROOT / "README.md").read_text()
    hits += [f"README.md: {m}" for m in re.findall(r".*GUIDE.*", readme)]
    assert not hits, "\n".join(hits)


def _import_graph():
    """{module: modules of lionjax it imports} from the sources (function-level imports
    included; ``from .. import twin`` is an edge to the subpackage, not to ``lionjax``)."""
    import ast

    root = pathlib.Path(lj.__file__).parent
    mods = {}
    for p in root.rglob("*.py"):
        parts = p.relative_to(root.parent).with_suffix("").parts
        mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    graph = {m: set() for m in mods}
    for m, p in mods.items():
        pkg = m if p.name == "__init__.py" else m.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom):
                base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1] if node.level else []
                tgt = ".".join([*base, *([node.module] if node.module else [])])
                subs = [f"{tgt}.{a.name}" for a in node.names if f"{tgt}.{a.name}" in mods]
                targets = subs + ([tgt] if len(subs) < len(node.names) else [])
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            graph[m] |= {t for t in targets if t in mods and t != m}
    return graph


def test_no_import_cycle():
    graph = _import_graph()
    assert graph["lionjax.diagnosis._core"]  # the graph is read
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(u):
        state[u] = 1
        path.append(u)
        for v in sorted(graph[u]):
            assert state.get(v) != 1, "import cycle: " + " -> ".join([*path[path.index(v) :], v])
            if v not in state:
                visit(v)
        path.pop()
        state[u] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


def test_import_leaves_the_ode_and_optimisation_libraries_unloaded():
    # every `lionjax` process pays its import (a cold `lionjax diagnose` too): diffrax and
    # optimistix (~0.4 s) load where an ODE is solved or a tuning starts
    import subprocess
    import sys

    code = (
        "import sys, lionjax, lionjax.cli; "
        "print(sorted(m for m in ('diffrax', 'optimistix', 'lineax') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
    # and they still load where they are used
    step = lj.DiffraxStep()
    assert type(step.solver).__name__ == "Kvaerno5"
