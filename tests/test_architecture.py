"""The architecture as tests: which file may import which, and what importing costs.

docs/architecture.md draws the layers; these tests keep the code honest about them.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from tmcl_server.module import TMCM6212
from tmcl_server.module.program import ProgramSupport
from tmcl_spec.commands import Opcode

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("tmcl_spec", "axes", "interpreter", "tmcl_server")
#: Libraries only some transports need: nothing else may import them.
TRANSPORT_LIBRARIES = ("can", "aiomqtt", "paho", "serial")


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST, package: str, type_only: bool = True) -> set[str]:
    """Every module a file imports, those only for type checkers included unless
    ``type_only`` is False (a hook's interface belongs to the layer that calls it, so a type
    needs no import against the layers' direction either)."""
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        if not type_only and isinstance(node, ast.If) and _is_type_checking(node):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                name = f"{base}.{node.module}" if node.module else base
            else:
                name = node.module or ""
            found.add(name)
            found.update(f"{name}.{alias.name}" for alias in node.names)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return found


def _graph() -> dict[str, set[str]]:
    """File-level import graph inside the product's packages."""
    files = {_module_name(p): p for package in PACKAGES for p in (ROOT / package).rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        imported = _imports(ast.parse(path.read_text()), package)
        graph[name] = {m for m in imported if m in files and m != name}
    return graph


def test_no_two_files_import_each_other_directly_or_in_a_loop() -> None:
    graph = _graph()
    state: dict[str, int] = {}  # 1 on the path, 2 done
    path: list[str] = []

    def walk(node: str) -> None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                loop = [*path[path.index(nxt):], nxt]
                pytest.fail("import loop: " + " -> ".join(loop))
            if nxt not in state:
                walk(nxt)
        path.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            walk(node)


@pytest.mark.parametrize(("package", "allowed"), [
    ("tmcl_spec", {"tmcl_spec"}),
    ("axes", {"axes", "tmcl_spec"}),
    ("interpreter", {"interpreter", "tmcl_spec"}),
])
def test_lower_layers_never_import_the_layers_above(package: str, allowed: set[str]) -> None:
    for name, imported in _graph().items():
        if name.split(".")[0] == package:
            above = {m for m in imported if m.split(".")[0] not in allowed}
            assert not above, f"{name} imports {sorted(above)}"


def test_the_vocabulary_needs_nothing_but_the_standard_library() -> None:
    for path in (ROOT / "tmcl_spec").rglob("*.py"):
        for module in _imports(ast.parse(path.read_text()), "tmcl_spec"):
            top = module.split(".")[0]
            assert top in sys.stdlib_module_names or top in ("tmcl_spec", "__future__"), (
                f"{path.name} imports {module}")


def _loaded_after(code: str) -> set[str]:
    result = subprocess.run(
        [sys.executable, "-c", code + "\nimport sys\nprint(' '.join(sorted(sys.modules)))"],
        capture_output=True, text=True, check=True, cwd=ROOT, timeout=60)
    return {m.split(".")[0] for m in result.stdout.split()}


#: Libraries of the optional views: plots and the web dashboard.
VIEW_LIBRARIES = ("matplotlib", "aiohttp")


def test_importing_the_package_codec_assembler_or_client_loads_no_transport_library() -> None:
    loaded = _loaded_after("import tmcl_server, tmcl_server.protocol, interpreter, "
                           "interpreter.assembler, interpreter.disassembler, tmcl_spec, "
                           "tmcl_server.tool, tmcl_server.tool.commands, tmcl_server.upload, "
                           "tmcl_server.decode, tmcl_server.tool.proxy, tmcl_server.capture")
    libraries = set(TRANSPORT_LIBRARIES) | set(VIEW_LIBRARIES)
    assert not loaded & libraries, sorted(loaded & libraries)
    assert "axes" not in loaded and "asyncio" not in loaded


@pytest.mark.parametrize("code", [
    "import tmcl_server.tool.commands",
    # the proxy and its capture; the whole tool's parser, which names `replay` without loading it
    "import tmcl_server.tool.proxy, tmcl_server.capture\n"
    "from tmcl_server.tool import build_parser\n"
    "build_parser().parse_args(['replay', 'x.jsonl'])\n"
    "build_parser().parse_args(['proxy', '--listen-tcp', '127.0.0.1:0'])",
])
def test_the_client_loads_nothing_of_the_server(code: str) -> None:
    """``tmcl`` (tmcl_server.tool) needs the codec, the names and the decoder, not the model;
    ``tmcl replay`` loads the simulator itself, when it runs."""
    loaded = _modules_loaded_after(code)
    server = {"tmcl_server.simulation", "tmcl_server.server", "interpreter.machine",
              "tmcl_server.replay", "tmcl_server.cli"}
    assert not {m for m in loaded if m in server or m.startswith(("tmcl_server.module",
                                                                    "tmcl_server.transports"))}
    assert not {m for m in loaded if m.split(".")[0] == "axes"}
    assert not loaded & {"asyncio", *TRANSPORT_LIBRARIES, *VIEW_LIBRARIES}, sorted(
        loaded & {"asyncio", *TRANSPORT_LIBRARIES, *VIEW_LIBRARIES})


def test_a_server_with_tcp_only_imports_neither_python_can_nor_mqtt() -> None:
    loaded = _loaded_after(
        "from tmcl_server import SimulatorThread\n"
        "with SimulatorThread(clock='virtual', tcp=['127.0.0.1:0']) as sim:\n"
        "    assert sim.tcp\n")
    assert not loaded & set(TRANSPORT_LIBRARIES), sorted(loaded & set(TRANSPORT_LIBRARIES))


def _modules_loaded_after(code: str) -> set[str]:
    result = subprocess.run(
        [sys.executable, "-c", code + "\nimport sys\nprint(' '.join(sorted(sys.modules)))"],
        capture_output=True, text=True, check=True, cwd=ROOT, timeout=60)
    return set(result.stdout.split())


def test_without_http_nothing_of_the_dashboard_is_imported() -> None:
    """The dashboard (``--http``) and its library are loaded only when a server opens it."""
    dashboard = ("aiohttp", "tmcl_server.dashboard")
    loaded = _modules_loaded_after(
        "from tmcl_server.cli import build_parser, config_from_args\n"
        "config = config_from_args(build_parser().parse_args(['--tcp', '127.0.0.1:0']))\n"
        "from tmcl_server import SimulatorThread\n"
        "with SimulatorThread(config) as sim:\n"
        "    assert sim.tcp\n")
    assert not {m for m in loaded if m.startswith(dashboard)}
    with_http = _modules_loaded_after(
        "from tmcl_server import SimulatorThread\n"
        "with SimulatorThread(clock='virtual', tcp=['127.0.0.1:0'], http=['127.0.0.1:0']) as sim:\n"
        "    assert sim.endpoints['http'][0].startswith('http://127.0.0.1:')\n")
    assert {"aiohttp", "tmcl_server.dashboard.web"} <= with_http


def test_every_opcode_of_the_module_type_has_exactly_one_handler() -> None:
    module = TMCM6212()
    own, standalone = set(TMCM6212.COMMANDS), set(ProgramSupport.COMMANDS)
    assert not own & standalone, "an opcode with two handlers"
    assert set(module.handlers) == set(module.type.commands) == set(Opcode)
    for opcode, handler in module.handlers.items():
        assert handler.__name__.startswith("_"), (opcode, handler)


#: Modules only POSIX systems have, and calls only they make: tmcl_server/platform.py holds them.
POSIX_ONLY_MODULES = {"fcntl", "termios", "tty", "pty", "resource"}
POSIX_ONLY_CALLS = {"add_signal_handler", "openpty", "ttyname", "flock", "tcflush", "prctl"}


def test_posix_only_calls_stay_behind_the_platform_seam() -> None:
    seam = ROOT / "tmcl_server" / "platform.py"
    offenders = []
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            if path == seam:
                continue
            tree = ast.parse(path.read_text())
            imported = {m.split(".")[0] for m in _imports(tree, "")}
            called = {node.attr for node in ast.walk(tree) if isinstance(node, ast.Attribute)}
            bad = (imported & POSIX_ONLY_MODULES) | (called & POSIX_ONLY_CALLS)
            if bad:
                offenders.append(f"{path.relative_to(ROOT)}: {sorted(bad)}")
    assert not offenders, offenders


def test_the_pytest_plugin_loads_nothing_of_the_simulator_until_a_fixture_is_used() -> None:
    """pip installs the plugin into every pytest run of the environment (issue 37, item 11):
    importing it must cost next to nothing (scripts/bench_startup.py --plugin measures it:
    about 1 ms, 180 ms when it imported the server).  The fixtures import the simulator."""
    loaded = _modules_loaded_after("import pytest\nimport tmcl_server.pytest_plugin")
    ours = {m for m in loaded if m.split(".")[0] in ("tmcl_server", "interpreter", "axes", "tmcl_spec")}
    assert ours == {"tmcl_server", "tmcl_server.pytest_plugin"}, sorted(ours)
    assert "asyncio" not in loaded
