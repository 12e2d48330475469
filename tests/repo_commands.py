"""Run the repository's entry scripts as a user does: a subprocess in the repo root, outputs under `root`.

A uniquely named module (several conftests share the name `conftest`): import it directly.
"""

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def run_command(root, *args: str, timeout: float = 600, env: dict | None = None) -> subprocess.CompletedProcess:
    """`python <args>` in the repo root with USHAPE_ROOT=root (its outputs/ go there) and `env` added; output
    captured."""
    env = {**os.environ, **(env or {}), "USHAPE_ROOT": str(root)}
    return subprocess.run([sys.executable, *args], cwd=REPO, env=env, capture_output=True, text=True, timeout=timeout)
