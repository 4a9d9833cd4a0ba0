"""What a new user meets first: the README's snippet runs, the documents read as text, --help reads as text."""

import pathlib
import re
import subprocess
import sys

import pytest

from sb3_icrl.common.utils import plain_docstring

ROOT = pathlib.Path(__file__).resolve().parents[1]
#: The ``sb3-icrl`` command, as its console script runs it
SB3_ICRL = [sys.executable, "-c", "import sys; from sb3_icrl.zoo.train import cli; sys.exit(cli())"]


def test_the_readme_python_snippet_runs(monkeypatch) -> None:
    from sb3_icrl import VICRL, PPOLagrangian

    # The snippet trains for minutes: its learn() calls return at once here, the rest runs as written
    monkeypatch.setattr(PPOLagrangian, "learn", lambda self, *args, **kwargs: self)
    monkeypatch.setattr(VICRL, "learn", lambda self, *args, **kwargs: self)
    readme = (ROOT / "README.md").read_text()
    (snippet,) = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    namespace: dict = {}
    exec(compile(snippet, "README.md", "exec"), namespace)
    assert namespace["costs"].shape == (len(namespace["pairs"].obs),)


def test_documents_hold_no_control_characters() -> None:
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        text = path.read_text()
        bad = sorted({hex(ord(char)) for char in text if ord(char) < 32 and char not in "\n\t"})
        assert not bad, f"{path.relative_to(ROOT)} holds control characters {bad}"


def test_plain_docstring_reduces_sphinx_roles() -> None:
    text = "Wraps :class:`~sb3_icrl.constraints.wrappers.LearnedCostVecEnvWrapper`, see :func:`sb3_icrl.train` and ``x``."
    assert plain_docstring(text) == "Wraps LearnedCostVecEnvWrapper, see sb3_icrl.train and `x`."
    assert plain_docstring(":data:`the noise <DYNAMICS_NOISE>`") == "the noise"


@pytest.mark.parametrize("command", ["train", "enjoy", "compare", "transfer", "benchmark"])
def test_help_reads_as_text(command: str) -> None:
    shown = subprocess.run([*SB3_ICRL, command, "--help"], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    assert not re.search(r":(class|func|meth|mod|data|attr):`", shown), shown


def test_the_command_lists_every_benchmark_verb() -> None:
    shown = subprocess.run([*SB3_ICRL, "--help"], capture_output=True, text=True, cwd=ROOT)
    assert "benchmark run|status|report|list" in shown.stdout + shown.stderr


@pytest.mark.parametrize("module", ["sb3_icrl.zoo.compare", "sb3_icrl.zoo.enjoy"])
def test_command_modules_run_with_python_m_without_a_warning(module: str) -> None:
    # The package must not import the module before ``runpy`` runs it (RuntimeWarning "found in sys.modules")
    shown = subprocess.run(
        [sys.executable, "-W", "error::RuntimeWarning", "-m", module, "--help"], capture_output=True, text=True, cwd=ROOT
    )
    assert shown.returncode == 0, shown.stderr
    assert "RuntimeWarning" not in shown.stderr
