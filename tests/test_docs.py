"""The documentation builds with warnings as errors, and every guide page is reachable from the table of contents."""

import importlib.util
import pathlib
import re
import subprocess
import sys

import pytest

DOCS = pathlib.Path(__file__).resolve().parent.parent / "docs"
# ``.. toctree::`` (rst) or ```{toctree} (MyST) and the indented or fenced entries after it
RST_TOCTREE = re.compile(r"^\.\. toctree::[^\n]*\n((?:[ \t]+[^\n]*\n|[ \t]*\n)*)", re.MULTILINE)
MYST_TOCTREE = re.compile(r"^```\{toctree\}[^\n]*\n(.*?)^```", re.MULTILINE | re.DOTALL)


def toctree_entries(page: pathlib.Path, root: pathlib.Path = DOCS) -> list[str]:
    """
    The documents a page's toctrees list, as paths relative to ``root`` without suffix.

    :param page: An ``.rst`` or ``.md`` page of the documentation
    :param root: The documentation's source folder
    :return: The listed documents
    """
    text = page.read_text(encoding="utf-8")
    blocks = RST_TOCTREE.findall(text) if page.suffix == ".rst" else MYST_TOCTREE.findall(text)
    entries = []
    for block in blocks:
        for line in block.splitlines():
            entry = line.strip()
            if not entry or entry.startswith(":"):
                continue  # blank line or an option such as :maxdepth:
            # "Title <doc>" entries name their document in angle brackets
            target = entry[entry.rfind("<") + 1 : -1] if entry.endswith(">") else entry
            # Relative to the page, or to the root with a leading "/"
            entries.append(target[1:] if target.startswith("/") else (page.parent / target).relative_to(root).as_posix())
    return entries


def reachable_documents() -> set[str]:
    """Every document reachable from ``docs/index.rst`` through toctrees."""
    seen: set[str] = set()
    pending = ["index"]
    while pending:
        name = pending.pop()
        if name in seen:
            continue
        seen.add(name)
        for suffix in (".rst", ".md"):
            page = DOCS / f"{name}{suffix}"
            if page.is_file():
                pending.extend(toctree_entries(page))
    return seen


def test_toctree_parser_reads_rst_and_myst_toctrees(tmp_path):
    index = tmp_path / "index.rst"
    index.write_text(
        ".. toctree::\n   :maxdepth: 2\n\n   guide/a\n   The B page <guide/b>\n   /top\n\nText\n   not/an/entry\n"
    )
    (tmp_path / "guide").mkdir()
    page = tmp_path / "guide" / "a.md"
    page.write_text("# A\n\n```{toctree}\n:maxdepth: 1\n\nsub/c\n```\n\n```python\nnot_an_entry\n```\n")
    assert toctree_entries(index, tmp_path) == ["guide/a", "guide/b", "top"]
    assert toctree_entries(page, tmp_path) == ["guide/sub/c"]


def test_every_guide_page_is_in_the_table_of_contents():
    reachable = reachable_documents()
    guide_pages = sorted(page.relative_to(DOCS).with_suffix("").as_posix() for page in (DOCS / "guide").glob("*.md"))
    assert guide_pages, "docs/guide holds no page"
    missing = [page for page in guide_pages if page not in reachable]
    assert not missing, f"Guide pages not reachable from docs/index.rst: {missing}; add them to a toctree."
    # Every toctree entry names an existing page
    dangling = [name for name in reachable if not any((DOCS / f"{name}{suffix}").is_file() for suffix in (".rst", ".md"))]
    assert not dangling, f"Toctree entries without a page: {dangling}"


def test_every_api_page_is_in_the_table_of_contents():
    reachable = reachable_documents()
    missing = [
        page.relative_to(DOCS).with_suffix("").as_posix()
        for page in (DOCS / "modules").glob("*.rst")
        if page.relative_to(DOCS).with_suffix("").as_posix() not in reachable
    ]
    assert not missing, f"API pages not reachable from docs/index.rst: {missing}"


@pytest.mark.slow  # 15-30 s on a free core, many minutes on a busy one; .ci/run builds the docs with -W anyway
@pytest.mark.skipif(
    any(importlib.util.find_spec(name) is None for name in ("sphinx", "myst_parser", "sphinx_rtd_theme")),
    reason="the docs extra is not installed (pip install -e '.[docs]')",
)
def test_docs_build_without_warnings(tmp_path):
    command = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html"]
    command += ["-d", str(tmp_path / "doctrees"), str(DOCS), str(tmp_path / "html")]
    result = subprocess.run(command, capture_output=True, text=True, timeout=1800)
    assert result.returncode == 0, f"sphinx-build -W failed:\n{result.stderr[-5000:]}"
    for page in ("index", "guide/algorithms", "guide/custom_method", "modules/icrl"):
        assert (tmp_path / "html" / f"{page}.html").is_file()
    # The example is included in its page, and the API reference documents the trainer's hook
    assert "LeastSquaresTrainer" in (tmp_path / "html" / "guide" / "custom_method.html").read_text(encoding="utf-8")
    assert 'id="sb3_icrl.icrl.trainer.ICRLTrainer.loss"' in (tmp_path / "html" / "modules" / "icrl.html").read_text(
        encoding="utf-8"
    )


def documented_modules() -> set[str]:
    """The modules named by an ``automodule`` directive of the API reference."""
    pattern = re.compile(r"^\.\. automodule:: ([\w.]+)\s*$", re.MULTILINE)
    return {name for page in (DOCS / "modules").glob("*.rst") for name in pattern.findall(page.read_text(encoding="utf-8"))}


def test_every_module_is_in_the_api_reference():
    package = DOCS.parent / "sb3_icrl"
    modules = {
        ".".join(path.relative_to(package.parent).with_suffix("").parts)
        for path in package.rglob("*.py")
        if path.name not in ("__init__.py", "__main__.py") and not path.name.startswith("_")
    }
    missing = sorted(modules - documented_modules())
    assert not missing, f"Modules missing from the API reference: {missing}; add an automodule to a docs/modules/*.rst page."
    unknown = sorted(name for name in documented_modules() if importlib.util.find_spec(name) is None)
    assert not unknown, f"The API reference documents modules that do not exist: {unknown}"


def test_every_extra_is_in_the_install_guide_with_its_packages():
    import configparser

    config = configparser.ConfigParser()
    config.read(DOCS.parent / "setup.cfg")
    guide = (DOCS / "guide" / "install.md").read_text(encoding="utf-8")
    rows = {match[0]: match[1] for match in re.findall(r"^\| `([\w-]+)` \| ([^|]*) \|", guide, re.MULTILINE)}
    for extra, requirements in config["options.extras_require"].items():
        assert extra in rows, f"the extra {extra!r} of setup.cfg is not in docs/guide/install.md's table"
        for requirement in requirements.split("\n"):
            requirement = requirement.split("#")[0].strip()
            package = re.split(r"[<>=!~ ]", requirement)[0]
            if package:
                assert f"`{package}`" in rows[extra], f"{extra}: {package} is not in its install.md row ({rows[extra]})"


def test_quickstart_describes_the_grid_world_recipes_and_when_the_map_is_logged():
    """The quickstart's account of the grid-world recipes and of the constraint/map image follows the recipes."""
    import yaml

    from sb3_icrl.zoo.train import get_parser

    recipes = DOCS.parent / "sb3_icrl" / "zoo_hyperparams"
    for algo in ("gacl", "bc2l", "mecl", "vicrl"):
        entries = yaml.safe_load((recipes / f"{algo}.yml").read_text())
        grid = {env: recipe for env, recipe in entries.items() if "GridWorld" in env}
        assert grid, algo
        for env, recipe in grid.items():
            assert recipe["forward_solver"] == "pi_lagrangian" and recipe["n_timesteps"] == 10000, (algo, env)
            assert "nominal_buffer_size=500" in recipe["planner_kwargs"], (algo, env)
    eval_freq = get_parser().get_default("eval_freq")
    assert eval_freq > 10000  # the quickstart's run logs its map only at its end
    text = " ".join((DOCS / "guide" / "quickstart.md").read_text().split())
    assert f"(`--eval-freq`, default {eval_freq} steps) and at the end of the run" in text
    assert "first command above logs it once, at step 10000" in text
