"""The README and docs/ as a newcomer reads them: a README of at most 400 lines, every relative link and
picture found, every module of the package in the layout, and a layout that follows the package."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
import yaml

from pipeline import io
from pipeline.bench.runs import declared_runs
from pipeline.reports import layout, readme
from pipeline.settings import load_params
from tests.project import REPOSITORY

README = REPOSITORY / "README.md"
DECLARED = declared_runs(load_params(REPOSITORY / "params.yaml"))
PAGES = sorted((REPOSITORY / "docs").glob("*.md"))
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def anchors(page: Path) -> set[str]:
    """The anchors GitHub gives a page's headings: lower case, punctuation dropped, spaces as hyphens."""
    headings = re.findall(r"^#+ (.+)$", re.sub(r"```.*?```", "", page.read_text(), flags=re.DOTALL), re.MULTILINE)
    return {re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-") for heading in headings}


def test_the_readme_is_at_most_400_lines() -> None:
    assert len(README.read_text().splitlines()) <= 400


def test_the_readme_starts_with_the_two_commands_and_the_results() -> None:
    """Its first screen: what it is, `make pipeline` and `make test`, then the generated headline
    with its picture, before the walkthrough."""
    text = README.read_text()
    positions = [text.index(mark) for mark in ("make pipeline", "make test", readme.HEADLINE_START,
                                               "](reports/comparison.png)", "<!-- walkthrough -->")]
    assert positions == sorted(positions)


@pytest.mark.parametrize("page", [README, *PAGES], ids=lambda page: page.relative_to(REPOSITORY).as_posix())
def test_every_relative_link_and_picture_is_found(page: Path) -> None:
    """Links and pictures relative to the page (README.md at the top, the pages in docs/) name files
    that exist, and a `#fragment` a heading of the page it names."""
    for target in LINK.findall(page.read_text()):
        if re.match(r"[a-z]+:", target):
            continue  # https:, mailto:
        name, _, fragment = target.partition("#")
        linked = (page.parent / name).resolve() if name else page
        assert linked.exists(), f"{page.name}: {target} is not there"
        if fragment:
            assert fragment in anchors(linked), f"{page.name}: {target} names no heading of {linked.name}"


def test_the_layout_lists_every_module_of_the_package_once() -> None:
    """Every .py file under pipeline/ has one line in docs/architecture.md's layout, linked."""
    section = (REPOSITORY / "docs" / "architecture.md").read_text().split(readme.LAYOUT_START)[1]
    section = section.split(readme.LAYOUT_END)[0]
    modules = [path for path in (REPOSITORY / "pipeline").rglob("*.py") if "__pycache__" not in path.parts]
    wings = [path for path in modules if path.name == "__init__.py" and path.parent.parent.name == "pipeline"]
    for module in modules:
        name = module.relative_to(REPOSITORY).as_posix()
        if module in wings:  # a wing's __init__ is its heading
            assert section.count(f"**`{module.parent.relative_to(REPOSITORY).as_posix()}/`**") == 1, name
        elif name != "pipeline/__init__.py":
            assert section.count(f"(../{name})") == 1, f"{name} is not listed once in the layout"


def package_copy(tmp_path: Path) -> Path:
    shutil.copytree(REPOSITORY / "pipeline", tmp_path / "pipeline", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPOSITORY / "pyproject.toml", tmp_path)
    return tmp_path / "pipeline"


def test_a_new_module_changes_the_layout_and_one_without_a_docstring_is_refused(tmp_path: Path) -> None:
    """A module added to a wing appears in its wing's list with its docstring's first paragraph (so
    `readme --check` fails until the layout is regenerated); a top-level module the import contract's
    layers do not name is listed after them; a module without a docstring stops the layout, named."""
    package = package_copy(tmp_path)
    before = layout.layout_section(package, tmp_path / "docs")
    (package / "tracker" / "alpha_beta.py").write_text('"""An alpha-beta tracker,\nfixed gains.\n\nMore."""\n')
    (package / "stray.py").write_text('"""A module of no wing."""\n')
    after = layout.layout_section(package, tmp_path / "docs")
    assert after != before
    assert "- [`pipeline/tracker/alpha_beta.py`](../pipeline/tracker/alpha_beta.py): An alpha-beta tracker, " \
           "fixed gains." in after.split("**`pipeline/association/`**")[0].split("**`pipeline/tracker/`**")[1]
    assert after.split("Not in the contract's layers:")[1].strip() == \
        "- [`pipeline/stray.py`](../pipeline/stray.py): A module of no wing."
    (package / "tracker" / "undocumented.py").write_text("x = 1\n")
    with pytest.raises(io.InputError, match="undocumented.py: the module has no docstring"):
        layout.layout_section(package, tmp_path / "docs")


def test_a_missing_marker_or_page_is_named(tmp_path: Path) -> None:
    """`readme` names the page whose markers are gone, and a page that is not there."""
    (tmp_path / "docs").mkdir()
    shutil.copy(README, tmp_path / "README.md")
    for page in ("results.md", "speed.md", "architecture.md"):
        shutil.copy(REPOSITORY / "docs" / page, tmp_path / "docs" / page)
    speed = tmp_path / "docs" / "speed.md"
    speed.write_text(speed.read_text().replace(readme.SPEED_END, ""))
    with pytest.raises(io.InputError, match="speed.md: the markers .* are missing"):
        readme.update_documents(tmp_path / "README.md", tmp_path / "docs", REPOSITORY / "reports",
                                REPOSITORY / "pipeline", DECLARED, check=True)
    speed.unlink()
    with pytest.raises(io.InputError, match="speed.md: no such file"):
        readme.update_documents(tmp_path / "README.md", tmp_path / "docs", REPOSITORY / "reports",
                                REPOSITORY / "pipeline", DECLARED, check=True)


def test_the_generated_sections_are_written_where_they_are_held(tmp_path: Path) -> None:
    """Emptied sections are filled again, each in its own file, and the rest of each file is kept;
    the pictures' links are relative to the file that shows them."""
    (tmp_path / "docs").mkdir()
    shutil.copytree(REPOSITORY / "reports", tmp_path / "reports", ignore=shutil.ignore_patterns("*.png"))
    docs = REPOSITORY / "docs"
    empty = {README: (readme.HEADLINE_START, readme.HEADLINE_END), docs / "results.md": (readme.START, readme.END),
             docs / "speed.md": (readme.SPEED_START, readme.SPEED_END),
             docs / "architecture.md": (readme.LAYOUT_START, readme.LAYOUT_END)}
    for source, (start, end) in empty.items():
        text = source.read_text()
        head, rest = text.split(start)
        (tmp_path / source.relative_to(REPOSITORY)).write_text(head + start + "\n" + end + rest.split(end)[1])
    changed = readme.update_documents(tmp_path / "README.md", tmp_path / "docs", tmp_path / "reports",
                                      package_copy(tmp_path), DECLARED)
    assert sorted(changed) == sorted(tmp_path / source.relative_to(REPOSITORY) for source in empty)
    for source in empty:
        assert (tmp_path / source.relative_to(REPOSITORY)).read_text() == source.read_text()


def test_a_measured_figure_typed_in_the_readmes_prose_is_refused_naming_its_line(tmp_path: Path) -> None:
    """A figure planted in hand-written prose (the kind that contradicted its table: "rejects 90.3 %" beside a
    generated 92.1 %) stops `readme`, naming the line; the same figure inside a generated section or in code
    is not prose; the committed README has none."""
    assert readme.prose_figures(README.read_text()) == []
    planted = README.read_text().replace("## What it found\n", "## What it found\n\nThe autoencoder rejects "
                                         "90.3 % of the false windows.\n", 1)
    (tmp_path / "README.md").write_text(planted)
    (tmp_path / "docs").mkdir()
    with pytest.raises(io.InputError, match=r"README.md: a measured figure .* line \d+: 'The autoencoder rejects 90.3"):
        readme.update_documents(tmp_path / "README.md", tmp_path / "docs", REPOSITORY / "reports",
                                REPOSITORY / "pipeline", DECLARED, check=True)
    assert readme.prose_figures("took 47 minutes\n`took 47 minutes`\n```\n47 min\n```\n"
                                f"{readme.RUN_START}\n47 min\n{readme.RUN_END}\n") == [(1, "took 47 minutes")]
    assert readme.prose_figures("Python 3.11, torch 2.13.0, 2 CPU cores, issue 29, at most 400 lines\n") == []


def test_the_committed_run_times_measured_the_code_of_the_committed_run() -> None:
    """reports/pipeline_speed.json (benchmarks/bench_pipeline.py) records each stage's code as its run hashed
    it; the committed dvc.lock must hash it the same, or the README's times are older than the code they
    measure: the README then names the files changed since (`readme.changed_since_timed`), until the benchmark
    runs again. A report from before that record gives no time in the README, only that it is not known."""
    speed = json.loads((REPOSITORY / "reports" / "pipeline_speed.json").read_text())
    lock = yaml.safe_load((REPOSITORY / "dvc.lock").read_text())["stages"]
    if "code" not in speed:  # a report from before the record: the README must say its time is not known
        assert "is not known" in readme.run_time_section(REPOSITORY / "reports")
        return
    stale = [name for name, code in speed["code"].items()
             if code != {dep["path"]: dep["md5"] for dep in lock[name].get("deps", []) if dep["path"].startswith("pipeline/")}]
    changed = readme.changed_since_timed(speed, REPOSITORY)
    assert bool(stale) == bool(changed)
    section = readme.run_time_section(REPOSITORY / "reports")
    assert all(f"`{name}`" in section for name in changed) and ("changed since" in section) == bool(changed), (
        f"stages timed on other code than dvc.lock's: {stale}; the README must name the files changed since")
