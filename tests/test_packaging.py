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


def test_a_kernel_numba_cannot_cache_still_runs_and_says_so(tmp_path):
    """Where numba finds no writable cache folder (a read-only install, no home), caching
    raises at decoration; fgcal compiles in the process instead, with one warning."""
    import subprocess
    import sys

    script = (
        "import numba.core.caching as caching\n"
        "caching.CacheImpl._locator_classes = []  # as if no cache folder were writable\n"
        "import numpy as np, fgcal\n"
        "print(fgcal.load_robot('abb_irb120').fk(np.zeros(6))[2, 3])\n"
    )
    run = subprocess.run(
        [sys.executable, "-P", "-c", script], capture_output=True, text=True, cwd=tmp_path, timeout=600, check=False
    )
    assert run.returncode == 0, run.stderr
    assert abs(float(run.stdout) - 0.63) < 1e-12  # the IRB 120's flange height at zero
    assert run.stderr.count("numba finds no writable folder") == 1, run.stderr
