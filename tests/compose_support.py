"""What the compose tests share: the compose command this machine has, the larns image they run."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
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


def tail(text: str, n: int = 30) -> str:
    return "\n".join(text.strip().splitlines()[-n:])


def sleep_until(wall_s: float) -> None:
    time.sleep(max(0.0, wall_s - time.time()))


class Compose:
    """``compose -p PROJECT -f FILE ARGS...`` with ``env``; asserts success unless ``check=False``."""

    def __init__(self, cmd: list[str], project: str, env: dict[str, str], file: Path = ROOT / "docker-compose.yml"):
        self.cmd, self.project, self.env, self.file = cmd, project, env, file

    def __call__(self, *args: str, timeout: float = 120, check: bool = True) -> subprocess.CompletedProcess:
        r = run([*self.cmd, "-p", self.project, "-f", str(self.file), *args], timeout=timeout, env=self.env, cwd=ROOT)
        if check:
            assert r.returncode == 0, f"compose {' '.join(args)} failed:\n{tail(r.stderr + r.stdout)}"
        return r

    def containers(self) -> dict[str, tuple[str, str]]:
        """service -> (container id, state), from the compose labels (one fast `docker ps`)."""
        out = run(["docker", "ps", "-a", "--filter", f"label=com.docker.compose.project={self.project}",
                   "--format", '{{.Label "com.docker.compose.service"}} {{.ID}} {{.State}}']).stdout
        return {svc: (cid, st) for svc, cid, st in (line.split() for line in out.splitlines() if line.strip())}

    def cid(self, service: str) -> str:
        c = self.containers().get(service)
        assert c, f"no container for {service}"
        return c[0]


def wait_started(cids: dict[int, str], t0: float, limit_s: float = 120.0) -> set[int]:
    """Wait until every station container ``cids[id]`` has printed its start line (on a loaded 2-core
    box, a dozen Python processes importing numpy/scipy/zenoh take a while), at most until
    ``t0 + limit_s``; the ids still waiting then."""
    waiting = set(cids)
    while waiting and time.time() - t0 < limit_s:
        for i in sorted(waiting):
            r = run(["docker", "logs", cids[i]])
            if f"[station {i}] scenario" in r.stdout + r.stderr:
                waiting.discard(i)
        time.sleep(0.5)
    return waiting


# ----------------------------------------------------------------- reading a recording's estimates

def at_index(s: dict, t_ns: int) -> int:
    """Index of the last estimate of station summary ``s`` logged before wall time ``t_ns``."""
    import numpy as np

    i = int(np.searchsorted(s["log_time_ns"], t_ns)) - 1
    assert i >= 0, "no estimate before the event"
    return i


def err_sigma(s: dict, i: int) -> tuple[float, float]:
    """(error to the truth, sqrt of the covariance's trace) of estimate ``i``, m."""
    import math

    import numpy as np

    return (float(np.linalg.norm(s["pos_m"][i] - s["truth_m"])),
            float(math.sqrt(max(np.trace(s["cov_m2"][i]), 0.0))))


def sim_rms(scn: Path, until_s: float, ids: list[int], start_s: dict, stop_s: dict) -> float:
    """Mean over 3 world seeds of the in-process simulator's RMS error of ``ids`` at ``until_s``."""
    import numpy as np

    from net.scenario import load
    from stations.sim import Simulator

    s = load(scn)
    k = [s.ids.index(i) for i in ids]
    out = []
    for seed in range(3):
        r = Simulator(s, seed=seed, start_s=start_s, stop_s=stop_s).run(until_s, [until_s])
        out.append(np.sqrt(np.mean(np.linalg.norm(r.pos_m[-1, k] - r.truth_m[k], axis=-1) ** 2)))
    return float(np.mean(out))


def assert_not_disturbed(summary: dict, t_ns: int, ids: list[int], after_s: float) -> None:
    """Stations ``ids`` move by < 1 sigma per axis from their last estimate before wall time ``t_ns``
    to their first estimate ``after_s`` wall s later (a join, a reconnection, a re-merge must not
    shake the network)."""
    import numpy as np

    for sid in ids:
        s = summary[sid]
        b = at_index(s, t_ns)
        a = int(np.searchsorted(s["log_time_ns"], t_ns + int(after_s * 1e9)))
        assert a < len(s["log_time_ns"]), (sid, "no estimate after the event")
        d = np.abs(s["pos_m"][a] - s["pos_m"][b])
        sig = np.sqrt(np.diag(s["cov_m2"][b]))
        assert np.all(d <= sig + 1e-6), (sid, d, sig)


def logs_and_down(dc: Compose, logs: Path, tag: str) -> None:
    """A compose run's end, whatever happened: the containers' logs kept in ``logs`` (unless written
    already), then ``down -v``."""
    if not logs.exists():       # failed before `down`: keep the containers' logs
        logs.write_text(dc("logs", "--no-color", check=False).stdout)
    print(f"[{tag}] container logs: {logs}", file=sys.stderr)
    dc("down", "-v", "--remove-orphans", timeout=120, check=False)
