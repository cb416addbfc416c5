"""The README's API tour runs as written."""

import re
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_tour_runs(capsys):
    text = README.read_text()
    block = re.search(r"## A tour of the API\n\n```python\n(.*?)```", text, re.S).group(1)
    namespace: dict = {}
    exec(compile(block, "README tour", "exec"), namespace)
    batch = namespace["batch"]
    assert np.isfinite(batch.pdop[0]) and np.isinf(batch.pdop[1])
    assert list(np.asarray(batch.status)) == [0, 3]
    assert len(namespace["idx_quasi"]) == 8
    np.testing.assert_allclose(
        namespace["best"].pdop,
        namespace["jp"].select.subset_dop(namespace["blocks"], namespace["idx_opt"])[0],
        rtol=1e-9,
    )
