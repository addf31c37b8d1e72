"""What the compose tests share: the compose command this machine has, the larns image they run."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def run(cmd, timeout=120, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, **kw)


def compose_cmd() -> list[str] | None:
    """``docker compose`` (v2 plugin) or ``docker-compose`` (v1), None without a Docker engine."""
    if shutil.which("docker") is None:
        return None
    try:
        if run(["docker", "info"], timeout=30).returncode != 0:
            return None
    except (OSError, subprocess.TimeoutExpired):
        return None
    for cmd in (["docker", "compose"], ["docker-compose"]):
        try:
            if shutil.which(cmd[0]) and run([*cmd, "version"], timeout=20).returncode == 0:
                return cmd
        except (OSError, subprocess.TimeoutExpired):
            pass
    return None


def larns_image() -> str:
    """``LARNS_TEST_IMAGE``, else ``larns:latest`` built from this tree (scripts/docker-build.sh: a few
    seconds when nothing changed since the last build)."""
    if os.environ.get("LARNS_TEST_IMAGE"):
        return os.environ["LARNS_TEST_IMAGE"]
    base = run([str(ROOT / "scripts/docker-base.sh")], timeout=900)
    if base.returncode != 0:
        pytest.skip(f"cannot build the local base image: {base.stderr.strip()[-300:]}")
    b = run([str(ROOT / "scripts/docker-build.sh"), "--tag", "larns:latest"], timeout=1200,
            env={**os.environ, "PYTHON": sys.executable})
    assert b.returncode == 0, b.stderr[-3000:]
    return "larns:latest"
