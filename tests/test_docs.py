"""The documentation site builds with ``mkdocs build --strict`` (every page, every API reference
entry resolved from the docstrings, no broken link)."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_mkdocs_build_strict(tmp_path):
    pytest.importorskip("mkdocs", reason="the docs extra is not installed")
    pytest.importorskip("mkdocstrings", reason="the docs extra is not installed")
    pytest.importorskip("material", reason="the docs extra is not installed")
    site = tmp_path / "site"
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"),
         "-d", str(site)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    # every page of the nav was written, and the API reference holds the entry points
    for page in ("index.html", "conventions/index.html", "formats/index.html",
                 "api/toplevel/index.html"):
        assert (site / page).is_file(), page
    api = (site / "api" / "toplevel" / "index.html").read_text()
    for name in ("jaxpose.dop", "jaxpose.solve_pnp", "jaxpose.refine_pose", "jaxpose.Pose"):
        assert f'id="{name}"' in api, name
    shutil.rmtree(site)
