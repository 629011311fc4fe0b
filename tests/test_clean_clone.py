"""A checkout with no ../shared and no data/ beside it: the suite passes, and the tests that need
SFINGE3D skip with one line naming `make fetch-data` (the TI .cfg ships in tests/radar/ti_cfg)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
NEEDS_DATA = ["tests/hand/test_sfinge3d.py", "tests/radar/test_config.py", "tests/data/test_skeletons.py"]


def test_without_shared_data_the_sfinge3d_tests_skip_with_a_hint(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "CI" and not k.startswith("PYTEST_")}
    env.update(HANDRADAR_SHARED=str(tmp_path / "no_shared"), HANDRADAR_DATA=str(tmp_path / "no_data"))
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rs", *NEEDS_DATA],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=600, check=False)
    out = done.stdout
    assert done.returncode == 0, out[-3000:]
    assert " passed" in out and " skipped" in out and "error" not in out.splitlines()[-1]
    assert "SFINGE3D not found" in out and "run `make fetch-data`" in out
    # the Visualizer .cfg tests ran from the repository's copy
    assert "test_config.py" not in "".join(line for line in out.splitlines() if line.startswith("SKIPPED"))
