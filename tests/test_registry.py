"""The library's layers, and a user's ICRL method trained and benchmarked by name after sb3_icrl.register_algorithm."""

import ast
import os
import pathlib
import subprocess
import sys
import textwrap

import pytest
import yaml
from stable_baselines3 import PPO

import sb3_icrl
from sb3_icrl import registry
from sb3_icrl.bc2l import BC2L
from sb3_icrl.common.saved import UNRECORDED_TRAINERS
from sb3_icrl.registry import ALGOS, ICRL_ALGOS, RegistrationError, register_algorithm
from sb3_icrl.run_folder import saved_as
from sb3_icrl.zoo import hyperparams as zoo_hyperparams
from sb3_icrl.zoo import runs as zoo_runs
from sb3_icrl.zoo.enjoy import main as enjoy_main
from sb3_icrl.zoo.train import main as train_main

PACKAGE = pathlib.Path(sb3_icrl.__file__).parent
#: The ICRL algorithms of the library
ICRL = (sb3_icrl.GACL, sb3_icrl.BC2L, sb3_icrl.MECL, sb3_icrl.VICRL)
#: The command line: it may import everything, nothing in the library imports it
COMMAND_LINE = ("sb3_icrl.zoo", "sb3_icrl.benchmark.cli", "sb3_icrl.benchmark.__main__")
#: Every library package and the modules below the command line that the command line leans on
LIBRARY = (
    "sb3_icrl",
    "sb3_icrl.common",
    "sb3_icrl.common.env_ids",
    "sb3_icrl.envs",
    "sb3_icrl.data",
    "sb3_icrl.icrl",
    "sb3_icrl.constraints",
    "sb3_icrl.ppo_lagrangian",
    "sb3_icrl.pi_lagrangian",
    "sb3_icrl.bc2l",
    "sb3_icrl.gacl",
    "sb3_icrl.mecl",
    "sb3_icrl.vicrl",
    "sb3_icrl.registry",
    "sb3_icrl.hyperparams",
    "sb3_icrl.run_folder",
    "sb3_icrl.metrics",
    "sb3_icrl.plots",
    "sb3_icrl.benchmark",
)


def _module_name(path: pathlib.Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_command_line(module: str) -> bool:
    return any(module == name or module.startswith(f"{name}.") for name in COMMAND_LINE)


def _imports_in(tree: ast.AST) -> list[tuple[str, int]]:
    """Every ``sb3_icrl`` module or name imported in ``tree``, at its top or inside a function, with its line."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names if alias.name.startswith("sb3_icrl")]
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("sb3_icrl"):
            found += [(f"{node.module}.{alias.name}", node.lineno) for alias in node.names]
    return found


def _imports(path: pathlib.Path) -> list[tuple[str, int]]:
    return _imports_in(ast.parse(path.read_text()))


def test_nothing_below_the_command_line_imports_it():
    upward = [
        f"{_module_name(path)}:{line} imports {target}"
        for path in sorted(PACKAGE.rglob("*.py"))
        if not _is_command_line(_module_name(path))
        for target, line in _imports(path)
        if _is_command_line(target)
    ]
    assert upward == []


def test_the_common_layer_imports_nothing_above_it():
    upward = [
        f"{_module_name(path)}:{line} imports {target}"
        for path in sorted((PACKAGE / "common").rglob("*.py"))
        for target, line in _imports(path)
        if not (target == "sb3_icrl.common" or target.startswith("sb3_icrl.common."))
    ]
    assert upward == []


def test_the_library_imports_its_modules_at_module_top():
    inside_functions = [
        f"{_module_name(path)}:{line} imports {target}"
        for path in sorted(PACKAGE.rglob("*.py"))
        if not _is_command_line(_module_name(path))
        for function in ast.walk(ast.parse(path.read_text()))
        if isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef))
        for target, line in _imports_in(function)
    ]
    assert inside_functions == []


def _import_graph() -> dict[str, set[str]]:
    """Module -> the ``sb3_icrl`` modules it imports; a name taken from a package's ``__init__`` counts as taken from
    the module that defines it (``from sb3_icrl import BC2L`` imports :mod:`sb3_icrl.bc2l`)."""
    paths = {_module_name(path): path for path in PACKAGE.rglob("*.py")}
    facades = {}
    for module, path in paths.items():
        if path.name == "__init__.py":
            body = ast.parse(path.read_text()).body
            facades[module] = {
                alias.asname or alias.name: node.module
                for node in body
                if isinstance(node, ast.ImportFrom) and node.module
                for alias in node.names
            }
    graph: dict[str, set[str]] = {module: set() for module in paths}
    for module, path in paths.items():
        for target, _ in _imports(path):
            package, _, name = target.rpartition(".")
            if target not in paths:  # a name, not a module
                target = facades.get(package, {}).get(name, package)
            if target in paths and target != module:
                graph[module].add(target)
    return graph


def test_the_import_graph_has_no_circle():
    graph = _import_graph()
    state: dict[str, int] = {}  # 1: on the path being walked, 2: done
    circles = []

    def walk(module: str, path: list[str]) -> None:
        state[module] = 1
        for target in sorted(graph[module]):
            if state.get(target) == 1:
                circles.append(" -> ".join([*path[path.index(target) :], target]))
            elif target not in state:
                walk(target, [*path, target])
        state[module] = 2

    for module in sorted(graph):
        if module not in state:
            walk(module, [module])
    assert circles == []


def test_zips_saved_before_they_named_their_algorithm_are_told_by_the_trainer():
    expected = {f"{a.default_trainer_class.__module__}.{a.default_trainer_class.__qualname__}": a.__name__ for a in ICRL}
    assert expected == UNRECORDED_TRAINERS


def test_library_packages_import_without_the_command_line():
    # One fresh interpreter: imports only add modules, so none of them alone pulls the command line in either
    script = "import sys\n" + "".join(f"import {name}\n" for name in LIBRARY)
    script += f"print([name for name in sys.modules if name.startswith({COMMAND_LINE!r})])\n"
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip() == "[]"


def test_old_command_line_names_are_the_library_s():
    assert zoo_hyperparams.ALGOS is ALGOS and zoo_hyperparams.ICRL_ALGOS is ICRL_ALGOS
    assert zoo_hyperparams.load_hyperparams is sb3_icrl.hyperparams.load_hyperparams
    assert zoo_runs.is_finished is sb3_icrl.run_folder.is_finished
    assert sb3_icrl.register_algorithm is register_algorithm


# ------------------------------------------------------------------------------------------------ registration


@pytest.fixture
def restore_registry():
    """Registrations made by a test are forgotten after it."""
    algos, icrl_algos, files = dict(ALGOS), list(ICRL_ALGOS), dict(registry.HYPERPARAMS_FILES)
    yield
    ALGOS.clear()
    ALGOS.update(algos)
    ICRL_ALGOS[:] = icrl_algos
    registry.HYPERPARAMS_FILES.clear()
    registry.HYPERPARAMS_FILES.update(files)


class _RenamedBC2L(BC2L):
    """BC2L under another name."""


def test_register_algorithm_adds_a_name_once(restore_registry, tmp_path):
    recipe = tmp_path / "renamed.yml"
    recipe.write_text("default:\n  n_timesteps: 100\n")
    register_algorithm("renamed", _RenamedBC2L, hyperparams=recipe)
    register_algorithm("renamed", _RenamedBC2L, hyperparams=recipe)  # a module imported twice
    assert ALGOS["renamed"] is _RenamedBC2L and ICRL_ALGOS.count("renamed") == 1
    assert registry.hyperparams_file("renamed") == recipe.resolve()
    assert sb3_icrl.hyperparams.load_hyperparams("renamed", "GridWorldWall-v0") == ({"n_timesteps": 100}, "default")
    register_algorithm("plain", PPO)
    assert "plain" not in ICRL_ALGOS  # told from the class: PPO learns no constraint


@pytest.mark.parametrize(
    "name, algo_class, options, message",
    [
        ("bc2l", _RenamedBC2L, {}, "The algorithm name 'bc2l' is taken"),
        ("My-Method", _RenamedBC2L, {}, "use lower case letters"),
        ("mine", dict, {}, "is not a subclass of stable_baselines3's BaseAlgorithm"),
        ("mine", _RenamedBC2L, {"hyperparams": "no/such/file.yml"}, "no hyper-parameter file"),
    ],
)
def test_register_algorithm_refuses_bad_input(restore_registry, name, algo_class, options, message):
    with pytest.raises(RegistrationError, match=message):
        register_algorithm(name, algo_class, **options)
    assert "mine" not in ALGOS


def test_an_unknown_algo_says_how_to_register_one(capsys):
    with pytest.raises(SystemExit):
        train_main(["--algo", "mymethod", "--env", "GridWorldWall-v0"])
    assert "register your own with sb3_icrl.register_algorithm in a module you name with --gym-packages" in (
        capsys.readouterr().err
    )


# ---------------------------------------------------------------- a user's method, end to end

USER_METHOD = """\
import pathlib

from sb3_icrl import BC2L, register_algorithm


class RenamedBC2L(BC2L):
    \"\"\"BC2L under another name: a user's method, defined outside the package.\"\"\"


register_algorithm("renamedbc2l", RenamedBC2L, hyperparams=pathlib.Path(__file__).with_name("renamedbc2l.yml"))
"""
#: A few hundred steps on the grid (the shipped BC2L recipe plans exactly: each step is cheap)
TINY = {"n_timesteps": 256, "n_steps": 128, "batch_size": 64}


@pytest.fixture
def user_method(tmp_path, monkeypatch, restore_registry):
    """A module in a folder of its own that registers a BC2L subclass as ``renamedbc2l``, on the path of this process
    and of the processes it starts."""
    name = f"user_method_{os.getpid()}_{tmp_path.name.replace('-', '_')}"
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / f"{name}.py").write_text(textwrap.dedent(USER_METHOD))
    shipped = yaml.safe_load((registry.DEFAULT_HYPERPARAMS_DIR / "bc2l.yml").read_text())
    entry = {**shipped["GridWorldWall-v0"], **TINY}
    (folder / "renamedbc2l.yml").write_text(yaml.safe_dump({"GridWorldWall-v0": entry}))
    monkeypatch.syspath_prepend(str(folder))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(folder), os.environ.get("PYTHONPATH", "")]))
    yield name
    sys.modules.pop(name, None)


def test_a_user_method_trains_by_name_and_runs_in_a_suite(user_method, tmp_path, capsys):
    from sb3_icrl.benchmark.cli import main as benchmark_main

    logs = tmp_path / "logs"
    argv = ["--algo", "renamedbc2l", "--env", "GridWorldWall-v0", "--gym-packages", user_method, "-f", str(logs)]
    assert train_main([*argv, "--seed", "0", "--eval-freq", "128", "--eval-episodes", "1", "--verbose", "0"]) == 0
    run = logs / "renamedbc2l" / "GridWorldWall-v0_1"
    assert (run / "finished.json").is_file()
    assert type(ALGOS["renamedbc2l"].load(run / "GridWorldWall-v0.zip")).__name__ == "RenamedBC2L"
    # Its models save what BC2L's save: enjoy takes them for --algo renamedbc2l, and BC2L's own stay BC2L's
    assert saved_as("renamedbc2l") == "bc2l" and saved_as("bc2l") == "bc2l"
    enjoy_argv = ["--algo", "renamedbc2l", "--env", "GridWorldWall-v0", "--gym-packages", user_method, "-f", str(logs)]
    assert enjoy_main([*enjoy_argv, "--no-render", "-n", "50", "--verbose", "0"]) == 0

    suite = tmp_path / "mine.yml"
    suite.write_text(
        yaml.safe_dump(
            {
                "description": "A user's method beside BC2L",
                "envs": ["GridWorldWall-v0"],
                "algos": ["bc2l", "renamedbc2l"],
                "seeds": [0],
                "steps": TINY["n_timesteps"],
                "eval_episodes": 2,
                "variants": {"tiny": {"hyperparams": {"n_steps": TINY["n_steps"], "batch_size": TINY["batch_size"]}}},
                "train_args": {"eval_freq": 128, "eval_episodes": 1},
                "gym_packages": [user_method],
            }
        )
    )
    # The runs train in processes of their own: each imports the suite's gym_packages
    assert benchmark_main(["run", str(suite), "-f", str(tmp_path / "suite"), "--jobs", "1"]) == 0
    for algo in ("bc2l", "renamedbc2l"):
        assert (tmp_path / "suite" / "mine" / "tiny" / algo / "GridWorldWall-v0_0" / "finished.json").is_file()
    assert "renamedbc2l" in capsys.readouterr().out
