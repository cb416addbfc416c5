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
        [
            sys.executable,
            "-m",
            "mkdocs",
            "build",
            "--strict",
            "-f",
            str(ROOT / "mkdocs.yml"),
            "-d",
            str(site),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    # every page of the nav was written, and the API reference holds the entry points
    for page in (
        "index.html",
        "conventions/index.html",
        "formats/index.html",
        "api/toplevel/index.html",
    ):
        assert (site / page).is_file(), page
    api = (site / "api" / "toplevel" / "index.html").read_text()
    for name in ("jaxpose.dop", "jaxpose.solve_pnp", "jaxpose.refine_pose", "jaxpose.Pose"):
        assert f'id="{name}"' in api, name
    shutil.rmtree(site)


_LAYERS = {"core": 1, "vision": 2, "pipelines": 3, "studies": 3, "commands": 3, "io": 3, "cli": 3}


def _layer(module: str) -> int | None:
    """Layer of a ``jaxpose.<top>...`` module as the design page defines it (None: the package
    root, which re-exports from every layer)."""
    parts = module.split(".")
    return _LAYERS.get(parts[1]) if len(parts) > 1 else None


def test_imports_go_only_downward():
    """The design page's rule: core never imports vision or the applications, vision never
    imports the applications (checked on every module's import statements)."""
    import ast

    src = ROOT / "src" / "jaxpose"
    bad = []
    for path in sorted(src.rglob("*.py")):
        rel = path.relative_to(src.parent).with_suffix("")
        module = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        own = _layer(module)
        if own is None:
            continue
        package = module if rel.name == "__init__" else module.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    targets = [".".join(base + ([node.module] if node.module else []))]
                else:
                    targets = [node.module or ""]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            for target in targets:
                if target.startswith("jaxpose.") and (_layer(target) or 0) > own:
                    bad.append(f"{module}:{node.lineno} imports {target}")
    assert not bad, "\n".join(bad)


def test_no_page_points_outside_the_repository():
    for path in [ROOT / "README.md", ROOT / "mkdocs.yml", *sorted((ROOT / "docs").rglob("*.md"))]:
        text = path.read_text()
        assert "../shared" not in text and "shared/docs" not in text, path
        assert "seed 00" not in text.lower(), path


def _code_blocks() -> list[tuple[str, str]]:
    """Every ``python`` block of the README and the docs pages, with where it comes from."""
    import re

    blocks = []
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        for i, code in enumerate(re.findall(r"```python\n(.*?)```", path.read_text(), re.S)):
            blocks.append((f"{path.relative_to(ROOT)} block {i}", code))
    return blocks


def test_code_blocks_name_only_what_exists():
    """The examples follow the API: every module they import, every name they import from it,
    and every ``jp.<name>`` (and ``jp.<module>.<name>``) they use exists in this checkout."""
    import ast
    import importlib

    import jaxpose as jp

    missing = []
    for where, code in _code_blocks():
        try:
            tree = ast.parse(code)
        except SyntaxError:  # a fragment such as "res.R, res.t": names only, no statements
            tree = ast.parse("\n".join(line for line in code.splitlines() if "=" in line) or "0")
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("jaxpose"):
                module = importlib.import_module(node.module)
                missing += [
                    f"{where}: {node.module}.{a.name}"
                    for a in node.names
                    if not hasattr(module, a.name)
                ]
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("jaxpose"):
                        importlib.import_module(a.name)
            elif isinstance(node, ast.Attribute):
                chain = []
                inner = node
                while isinstance(inner, ast.Attribute):
                    chain.append(inner.attr)
                    inner = inner.value
                if isinstance(inner, ast.Name) and inner.id == "jp":
                    obj = jp
                    for attr in reversed(chain):
                        if not hasattr(obj, attr):
                            missing.append(f"{where}: jp.{'.'.join(reversed(chain))}")
                            break
                        obj = getattr(obj, attr)
    assert not missing, "\n".join(sorted(set(missing)))


def test_conventions_page_table_holds():
    """The conventions page's table of jaxpose, SciPy and OpenCV equivalents, checked (float64:
    conftest turns it on)."""
    import cv2
    import numpy as np
    from scipy.spatial.transform import Rotation

    import jaxpose as jp

    rng = np.random.default_rng(7)
    for _ in range(5):
        angles = rng.uniform(-1.2, 1.2, 3)
        t = rng.normal(size=3)
        pose = jp.Pose.from_euler(angles, t, "XYZ")
        R = np.asarray(pose.R)
        np.testing.assert_allclose(R, Rotation.from_euler("XYZ", angles).as_matrix(), atol=1e-12)
        # the default sequence is "XYZ"
        np.testing.assert_allclose(np.asarray(jp.Pose.from_euler(angles, t).R), R, atol=1e-12)
        ext = np.asarray(pose.euler("xyz"))
        np.testing.assert_allclose(ext, Rotation.from_matrix(R).as_euler("xyz"), atol=1e-9)
        np.testing.assert_allclose(np.rad2deg(ext), cv2.RQDecomp3x3(R)[0], atol=1e-7)
        rvec = np.asarray(pose.rotvec)
        np.testing.assert_allclose(rvec, Rotation.from_matrix(R).as_rotvec(), atol=1e-9)
        np.testing.assert_allclose(rvec, cv2.Rodrigues(R)[0].ravel(), atol=1e-9)
        q = np.asarray(pose.quat)
        x, y, z, w = Rotation.from_matrix(R).as_quat()
        np.testing.assert_allclose(q, np.sign(w) * np.array([w, x, y, z]), atol=1e-9)
        assert q[0] >= 0
        # OpenCV's rvec/tvec meaning: cv2.projectPoints agrees with the one projection
        camera = jp.PinholeCamera.from_K([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
        pts = rng.normal(size=(6, 3)) * 0.3
        pose = jp.Pose(R, np.array([0.1, -0.2, 5.0]))
        ours = np.asarray(camera.project(pose.apply(pts)))
        cv, _ = cv2.projectPoints(pts, rvec, np.asarray(pose.t), np.asarray(camera.K), None)
        np.testing.assert_allclose(ours, cv.reshape(-1, 2), atol=1e-8)
        # the tangent convention: R <- exp([omega]x) R, t <- t + rho
        xi = rng.normal(size=6) * 0.1
        moved = pose.retract(xi)
        np.testing.assert_allclose(np.asarray(moved.t), np.asarray(pose.t) + xi[:3], atol=1e-12)
        np.testing.assert_allclose(
            np.asarray(moved.R), Rotation.from_rotvec(xi[3:]).as_matrix() @ R, atol=1e-12
        )
