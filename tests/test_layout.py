"""The project's layout, read from the code with ast: meshing imports no physics, no import circle, no test fixture
in a library package."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ("contracts", "fem_offline", "training", "service", "pipeline")


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    """Every module of the library packages by dotted name (a package by its __init__.py)."""
    return {_module_name(p): p for package in LIBRARY for p in sorted((ROOT / package).rglob("*.py"))}


def _is_type_checking(node: ast.AST) -> bool:
    return isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)


def _imports(path: Path, name: str, modules: dict[str, Path], *, type_checking: bool = False) -> set[str]:
    """What module `name` (at `path`) imports anywhere, inside functions too, relative imports resolved: `import X`
    gives X; `from X import a` gives X.a where that is one of `modules`, else X. Imports under `if TYPE_CHECKING:`
    only with `type_checking` (they never run)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    stack: list[ast.AST] = [ast.parse(path.read_text())]
    while stack:
        node = stack.pop()
        if not type_checking and _is_type_checking(node):
            stack += node.orelse
            continue
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join([*parts[: len(parts) - node.level + 1], *([base] if base else [])])
            found.update(f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names)
        stack += ast.iter_child_nodes(node)
    return found


def _graph() -> dict[str, set[str]]:
    """Module -> the library modules it imports."""
    modules = _modules()
    return {name: {n for n in _imports(path, name, modules) if n in modules and n != name}
            for name, path in modules.items()}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle of `graph` (its modules in order, the first again at the end), or None: a depth-first search
    that meets a module still on its path."""
    state: dict[str, int] = {}  # 1: on the path, 2: done

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        for dep in sorted(graph[node]):
            if state.get(dep) == 1:
                return path[path.index(dep):] + [dep]
            if dep not in state and (found := visit(dep, [*path, dep])):
                return found
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node, [node])):
            return found
    return None


@pytest.mark.parametrize("package", ["fem_offline.geometry", "fem_offline.labelmap"])
def test_meshing_imports_nothing_from_the_fe(package):
    """Meshing derives its node sets itself: no module of geometry/ or labelmap/ imports fem_offline.fe, anywhere in
    the file (a function's import and a TYPE_CHECKING import included)."""
    modules = _modules()
    for name, path in modules.items():
        if name == package or name.startswith(f"{package}."):
            imported = _imports(path, name, modules, type_checking=True)
            fe = {n for n in imported if n.split(".")[:2] == ["fem_offline", "fe"]}
            assert not fe, (name, fe)


def test_the_module_graph_reader_sees_a_circle():
    """The search finds a circle where there is one and none in a chain, and the graph holds the imports that run, so
    the next tests can fail."""
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
    graph = _graph()
    assert "training.export" in graph["training.fit"]  # relative
    assert "training.report" in graph["training.materials"]  # inside a function
    assert "fem_offline.geometry.guide_patch" in graph["fem_offline.fe.guide"]  # `from package import module`
    assert "fem_offline.geometry.mesh" not in graph["fem_offline.fe.boundary"]  # under TYPE_CHECKING only


def test_no_import_circle_among_the_library_modules():
    """Across contracts, fem_offline, training, service and pipeline, no module imports itself through others, a
    function's import included (it runs whenever that function does)."""
    assert _cycle(_graph()) is None, " -> ".join(_cycle(_graph()))


def test_the_library_packages_import_each_other_one_way():
    """Collapsed to the packages, the imports form no circle either (data flows one way, through files)."""
    packages = {p: set() for p in LIBRARY}
    for name, deps in _graph().items():
        packages[name.split(".")[0]] |= {d.split(".")[0] for d in deps} - {name.split(".")[0]}
    assert _cycle(packages) is None, " -> ".join(_cycle(packages))


def test_no_test_fixture_lives_in_a_library_package():
    """Fixtures and tests live in tests/ (or studies/): no fixtures*, conftest or test_* module in a library package,
    and no library module imports pytest or hypothesis."""
    for name, path in _modules().items():
        assert not path.name.startswith(("fixtures", "conftest", "test_")), name
        for node in ast.walk(ast.parse(path.read_text())):
            targets = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                       [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            assert not [t for t in targets if t.split(".")[0] in ("pytest", "hypothesis")], (name, targets)


# The service's runtime apart from the tools that drive it; the library apart from studies and benchmarks.
DRIVERS = ("studies", "bench", "tools")  # packages that run or measure the library, never imported by it


def _driver_imports(path: Path, name: str, drivers: tuple[str, ...]) -> list[str]:
    """The packages among `drivers` that a module imports anywhere, a function's and a TYPE_CHECKING import included."""
    return sorted(m for m in _imports(path, name, {}, type_checking=True) if m.split(".")[0] in drivers)


def test_the_service_runtime_imports_none_of_its_tools():
    """Importing the app, building it and loading `python -m service` brings in no load test, soak, browser
    driver or Playwright, nor any package that drives the service (in a fresh interpreter: sys.modules)."""
    import subprocess
    import sys

    code = ("import sys, service.__main__; from service.app import create_app; create_app(); "
            "print([m for m in sys.modules if m.split('.')[0] in ('tools', 'bench', 'studies', 'playwright', 'psutil') "
            "or m.rpartition('.')[2] in ('loadtest', 'soak', 'browser')])")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[]", run.stdout


def test_the_import_reader_sees_a_driver_import():
    """The reader finds bench's own imports of studies and tools, so the next tests can fail."""
    assert {"studies", "tools"} <= set(_driver_imports(ROOT / "bench" / "service.py", "bench.service", DRIVERS))


@pytest.mark.parametrize("package", LIBRARY)
def test_no_library_module_imports_studies_bench_or_tools(package):
    """Nothing in contracts, fem_offline, training, service or pipeline imports a study, a benchmark or a tool:
    they run the library, the library never runs them."""
    found = {name: _driver_imports(path, name, DRIVERS) for name, path in _modules().items()
             if name.split(".")[0] == package}
    assert not {name: f for name, f in found.items() if f}


def test_the_tools_import_nothing_of_the_project():
    """tools/ drives a running service from outside (HTTP, a browser): it imports no project package but itself."""
    for path in sorted((ROOT / "tools").glob("*.py")):
        assert not _driver_imports(path, _module_name(path), (*LIBRARY, "studies", "bench")), path.name


# The scene: one typed contract (contracts/scene), read through its fields by every stage.
SCENE_OWNER = "contracts.scene.schema"
SCENE_READERS = (*LIBRARY, "studies", "bench")
OTHER_SCENES = {"service.viewer", "bench.viewer"}  # there a scene is what the viewer page draws (scene.json)


def _scene_by_key(tree: ast.AST) -> list[str]:
    """Where a module reads a scene as a dict, a section of the schema by string key (`x.scene["guide"]`,
    `x.spec.get("effects", {})`, `scene["tissues"]`, `raw["scene"]["mesh"]`), or types a `scene` or `spec` field as
    a dict."""
    from contracts.scene import Scene

    def scene_like(node: ast.AST) -> bool:
        return (isinstance(node, ast.Attribute) and node.attr in ("scene", "spec")
                or isinstance(node, ast.Name) and node.id in ("scene", "spec")
                or isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant)
                and node.slice.value in ("scene", "spec"))

    def section(node: ast.AST | None) -> bool:
        return isinstance(node, ast.Constant) and node.value in Scene.model_fields

    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript) and scene_like(node.value) and section(node.slice):
            found.append(ast.unparse(node))
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get"
              and scene_like(node.func.value) and section(node.args[0] if node.args else None)):
            found.append(ast.unparse(node))
        elif (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
              and node.target.id in ("scene", "spec") and "dict" in ast.unparse(node.annotation)):
            found.append(ast.unparse(node))
    return found


def test_the_scene_reader_sees_the_dict_reads_it_replaced():
    """The check finds the reads of a scene by key that training, the service and the contracts made before the
    scene was typed (and leaves a key that is no section of the schema alone), so the next test can fail."""
    code = ('spec = manifest.scene["label_map"]\nv = m.scene.get("solver", {})\nt = m.scene.spec["guide"]["tip_mm"]\n'
            'g = spec.get("effects", {})\nt = scene["tissues"][name]\nx = raw["scene"]["mesh"]\n'
            'class SceneInfo:\n    spec: dict[str, Any]\nr = scene["regions"]\n')
    assert sorted(_scene_by_key(ast.parse(code))) == sorted([
        "manifest.scene['label_map']", "m.scene.get('solver', {})", "m.scene.spec['guide']", "spec.get('effects', {})",
        "scene['tissues']", "raw['scene']['mesh']", "spec: dict[str, Any]"])


def test_the_scene_contract_is_defined_once_and_read_through_its_fields():
    """Only contracts/scene/schema.py defines a Scene class, and no module of the library, the studies or the
    benchmarks reads a scene by key or types one as a dict: each field is read typed, with the schema's one default."""
    defined, by_key = [], {}
    for package in SCENE_READERS:
        for path in sorted((ROOT / package).rglob("*.py")):
            name = _module_name(path)
            if name in OTHER_SCENES:
                continue
            tree = ast.parse(path.read_text())
            defined += [name for n in ast.walk(tree) if isinstance(n, ast.ClassDef) and n.name == "Scene"]
            if found := _scene_by_key(tree):
                by_key[name] = found
    assert defined == [SCENE_OWNER]
    assert by_key == {}
