"""Compose keys as in trusted systems (issue 32, item 3 bar): no container but the one-shot `keys`
service can read ``ca.key`` or another enclave's ``key.pem``. The test brings up part of the real
``docker-compose.yml`` (stations 1-3, the aircraft, the recorder, the viewer), hot-joins station 11
the documented way, and inspects every container of the project: its mounts (``docker inspect``)
and what its mounted folders hold (``docker exec find``). About a minute once the image exists.

Skipped, with the reason, when no Docker engine or compose answers. ``LARNS_TEST_IMAGE=name:tag``
uses a ready image; otherwise ``scripts/docker-build.sh`` builds ``larns:latest`` (as
tests/larns/test_compose.py does)."""

from __future__ import annotations

import json
import os
import time

import pytest
from compose_support import ROOT, compose_cmd, larns_image, run

# whole-product stage (marker matrix), with the other compose tests
pytestmark = [pytest.mark.compose, pytest.mark.matrix, pytest.mark.timeout(900)]



COMPOSE = compose_cmd()
if COMPOSE is None:
    pytest.skip("compose tests need a Docker engine and docker compose", allow_module_level=True)
_run, _image = run, larns_image


OWN = {"station1": "station-1", "station2": "station-2", "station3": "station-3", "station11": "station-11",
       "aircraft": "aircraft-ac1", "recorder": "recorder", "viewer": "monitor"}


def test_only_the_keys_service_reads_ca_key_or_anothers_key(tmp_path):
    from net.bus import free_tcp_ports

    image = _image()
    project = f"larnskeys{os.getpid()}"
    env = {**os.environ, "LARNS_IMAGE": image, "LARNS_SCENARIO": "seed000", "LARNS_JOIN_SCENARIO": "seed000-join",
           "LARNS_RUN": "compose-keys-test", "LARNS_UID": str(os.getuid()), "LARNS_GID": str(os.getgid()),
           "LARNS_EPOCH": str(int(time.time()) + 5), "LARNS_VIEW_PORT": str(free_tcp_ports(1)[0])}

    def dc(*args, timeout=240, check=True):
        r = _run([*COMPOSE, "-p", project, "-f", str(ROOT / "docker-compose.yml"), *args], timeout=timeout,
                 env=env, cwd=ROOT)
        assert not check or r.returncode == 0, f"compose {args}: {(r.stderr + r.stdout)[-2000:]}"
        return r

    try:
        dc("up", "-d", "station1", "station2", "station3", "aircraft", "recorder", "viewer")
        add = dc("run", "--rm", "keys", "add", "/keys", "--station", "11")
        assert "exported to" in add.stdout, add.stdout + add.stderr
        dc("--profile", "hotjoin", "up", "-d", "--no-deps", "station11")
        time.sleep(8.0)
        out = _run(["docker", "ps", "-a", "--filter", f"label=com.docker.compose.project={project}",
                    "--format", '{{.Label "com.docker.compose.service"}} {{.ID}} {{.State}}']).stdout
        containers = [line.split() for line in out.splitlines() if line.strip()]
        services = {svc for svc, _cid, _st in containers}
        assert set(OWN) | {"keys", "epoch"} <= services, services
        master = f"{project}_keystore"
        seen_master = []
        for svc, cid, state in containers:
            mounts = json.loads(_run(["docker", "inspect", "--format", "{{json .Mounts}}", cid]).stdout)
            if any(m.get("Name") == master for m in mounts):
                seen_master.append(svc)
            if svc not in OWN:
                continue
            assert state == "running", (svc, state, _run(["docker", "logs", "--tail", "20", cid]).stderr)
            dests = [m["Destination"] for m in mounts]
            found = _run(["docker", "exec", cid, "find", *dests, "(", "-name", "ca.key", "-o", "-name", "key.pem",
                          ")"]).stdout.split()
            assert found == [f"/keys/{OWN[svc]}/key.pem"], (svc, found)
            listing = _run(["docker", "exec", cid, "ls", "/keys", "/keys/certs"]).stdout
            assert "ca.crt" in listing and "station-2.pem" in listing and "station-11.pem" in listing, (svc, listing)
        assert seen_master == ["keys"], seen_master       # (the one-shot `run --rm` is gone already)
        # the viewer's part of the keystore: ca.crt, public certificates, its own enclave only
        viewer = [c for s, c, _ in containers if s == "viewer"][0]
        assert _run(["docker", "cp", f"{viewer}:/keys", str(tmp_path / "viewer-keys")]).returncode == 0
        time.sleep(4.0)
    finally:
        dc("--profile", "hotjoin", "down", "-v", "--remove-orphans", timeout=180, check=False)
    # the processes ran secure on these mounts: every recorded message signed by its sender,
    # checked offline with no more than the viewer holds
    from larns.analysis.summary import summarize
    from net.security import Keystore

    mcap = ROOT / "runs" / "compose-keys-test.mcap"
    try:
        s = summarize([mcap], keystore=Keystore(tmp_path / "viewer-keys"))
    finally:
        mcap.unlink(missing_ok=True)
    assert s["refused"] == [], s["refused"][:5]
    assert {1, 2, 3} <= {sid for sid, v in s["stations"].items() if v.get("navs", 0) >= 5}, s["stations"]
