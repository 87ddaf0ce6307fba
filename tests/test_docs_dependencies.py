"""docs/development.md's dependency table says what pyproject.toml installs, all of it."""

from __future__ import annotations

import re
import tomllib

from tests.daemonkit import REPO


def _name(requirement: str) -> str:
    return re.split(r"[<>=!~\[; ]", requirement, maxsplit=1)[0].strip().lower()


def _declared() -> dict[str, set[str]]:
    """Each package and where it is installed from: "the package" or each extra's name."""
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    found = {_name(r): {"the package"} for r in project["dependencies"]}
    for extra, requirements in project["optional-dependencies"].items():
        for requirement in requirements:
            found.setdefault(_name(requirement), set()).add(f"`{extra}`")
    return found


def _documented() -> dict[str, str]:
    text = (REPO / "docs/development.md").read_text()
    table = text.split("| package | installed with | what for |", 1)[1].split("\n\n", 1)[0]
    rows: dict[str, str] = {}
    for line in table.strip().splitlines()[1:]:
        packages, where, _ = (cell.strip() for cell in line.strip("|").split("|"))
        for package in packages.split(","):
            rows[package.strip().lower()] = where
    return rows


def test_every_dependency_is_in_the_table_with_where_it_comes_from() -> None:
    declared = _declared()
    documented = _documented()
    assert set(documented) == set(declared)
    # A test extra repeats the plot and NetCDF packages: the table may name either.
    wrong = {p: (w, declared[p]) for p, w in documented.items() if w not in declared[p]}
    assert wrong == {}
