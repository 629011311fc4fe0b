"""The Python example of docs/architecture.md#python-api runs as written and prints what its comment says."""

from __future__ import annotations

import contextlib
import io
import re

from handradar.provenance import REPO_ROOT


def test_python_api_example_runs_and_prints_its_commented_ssim():
    text = (REPO_ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    section = text[text.index("## Python API"):text.index("## Commands")]
    code = section[section.index("```python") + len("```python"):section.rindex("```")]
    commented = float(re.search(r'print\("SSIM:".*#\s*([0-9.]+)', code).group(1))
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, "docs/architecture.md#python-api", "exec"), {})
    printed = float(out.getvalue().split("SSIM:")[1].split()[0])
    assert abs(printed - commented) < 0.002, (printed, commented)
