"""Every subpackage ships: pyproject lists packages explicitly (for the package-dir mapping)."""

from __future__ import annotations

import tomllib

from conftest import REPO


def test_every_subpackage_is_listed():
    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    found = {"fgcal"} | {
        "fgcal." + p.parent.relative_to(REPO / "fgcal").as_posix().replace("/", ".")
        for p in (REPO / "fgcal").rglob("__init__.py")
        if p.parent != REPO / "fgcal"
    }
    assert found <= listed, f"missing from [tool.setuptools] packages: {sorted(found - listed)}"
    assert {"fgcal.factors", "fgcal.datasets"} <= listed
    assert config["package-dir"]["fgcal.factors"] == "factors"
