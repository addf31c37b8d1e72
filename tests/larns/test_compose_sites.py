"""Two sites, a Zenoh router each, linked over a backbone network; the backbone cut and healed
(issue 33, item 7; docs/deploy.md "Two sites, a router each").

``scripts/compose-sites.py`` writes the compose file: stations 1-5 on the Docker network ``site_a``,
6-10 on ``site_b``, each a Zenoh client of its own site's router only (``larns router``; ``router_a``
on ``site_a`` + ``backbone``, ``router_b`` on ``site_b`` + ``backbone``, dialling ``router_a``), a
recorder on each site, secure by default (the keystore of docker-compose.yml: TLS, access control,
signed messages). One module-scoped run, at ``--speed 5`` on seed000's world with 50 ms slots in a
0.6 s cycle (as tests/larns/test_compose.py):

======================  ======================================================================
wall s after start      event
======================  ======================================================================
before                  ``up -d`` of the whole file; the timeline starts when every station
                        process has printed its start line
30                      ``docker network disconnect`` of both routers from ``backbone``
+20                     ``docker network connect`` of both again (the field is whole again)
+25                     ``down -v`` (each recorder finishes its MCAP on SIGTERM)
======================  ======================================================================

What the tests check, from the two recordings (``runs/compose-sites-test-a.mcap``, ``-b.mcap``;
container logs ``runs/compose-sites-test.log``): one field before the cut (each recorder hears all
10 stations, ranges cross the backbone, survey converged); the cut really splits it (no message of
the other site reaches a site while cut); each site keeps surveying on its own through the cut
(from its own recorder: navs with no pause over 3 s, survey updates, estimates within their
uncertainty of the truth); the sites merge again after the heal (each recorder hears the other
site within 10 s, ranges between the sites resume, the navs list the other site's stations as
members again, no station moves by more than 1 sigma when the other site comes back) and stay
consistent; both recordings complete. About 2.5 min of wall time once the
image exists (``LARNS_TEST_IMAGE=name:tag`` uses a ready one, else scripts/docker-build.sh builds
``larns:latest``); skipped with the reason when no Docker engine or compose answers.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from compose_support import (ROOT, Compose, assert_not_disturbed, at_index, compose_cmd, err_sigma, larns_image,
                             logs_and_down, run, sim_rms, sleep_until, wait_started)
from scenario_text import random_world

# whole-product stage (marker matrix), with the other compose tests
pytestmark = [pytest.mark.compose, pytest.mark.matrix, pytest.mark.timeout(900)]

COMPOSE = compose_cmd()
if COMPOSE is None:
    pytest.skip("compose tests need a Docker engine and docker compose", allow_module_level=True)

# tests/conftest.py runs the modules that have this last, after every other test, on their own
start_image_build = larns_image

SPEED, CYCLE_S = 5.0, 0.6
SITES = {"a": [1, 2, 3, 4, 5], "b": [6, 7, 8, 9, 10]}
CONVERGE_WALL_S, CUT_WALL_S, RUN_ON_WALL_S = 30.0, 20.0, 25.0
GRACE_S = 2.0        # wall s after the disconnect for messages already on their way
MERGE_S = 10.0       # each site hears the other again within this many wall s of the heal
PAUSE_S = 3.0        # the longest silence of a station in its own site's recorder
WHOLE_SHARE = 0.8    # share of a station's last navs that list every station of the other site
NAME = "compose-sites-test"
SCENARIO = random_world("sites", 10, [], cycle_s=CYCLE_S, slot_s=0.05,
                        description="seed000's world on two sites; 50 ms slots in a 0.6 s cycle (tests)")


def _site(sid: int) -> str:
    return "a" if sid in SITES["a"] else "b"


@dataclass
class Recording:
    """One recorder's file: per topic the log times (ns), the station summaries, the navs' members."""
    path: Path
    times: dict[str, np.ndarray] = field(default_factory=dict)
    members: dict[int, list[tuple[int, tuple]]] = field(default_factory=dict)   # sid -> [(log ns, members)]
    summary: dict = field(default_factory=dict)
    unsigned_navs: int = 0

    @classmethod
    def read(cls, path: Path) -> Recording:
        from mcap.reader import make_reader

        from larns.analysis.summary import mcap_station_summary
        from net import messages as M
        from net import security as S

        rec, times = cls(path), defaultdict(list)
        with open(path, "rb") as f:
            for _s, ch, m in make_reader(f).iter_messages():
                times[ch.topic].append(m.log_time)
                if M.is_nav_key(ch.topic):
                    rec.unsigned_navs += S.split_signed(m.data) is None
                    sid = int(ch.topic.split("/")[2])
                    rec.members.setdefault(sid, []).append((m.log_time, tuple(M.decode(m.data)[0]["members"])))
        rec.times = {k: np.sort(np.asarray(v, np.int64)) for k, v in times.items()}
        rec.summary = mcap_station_summary(path)
        return rec

    def of(self, sid: int, what: str = "nav") -> np.ndarray:
        """Log times of station ``sid``'s ``what`` (its navs under any tile: net/tiles.py)."""
        from net import messages as M

        if what == "nav":
            ts = [t for k, t in self.times.items() if M.is_nav_key(k) and k.split("/")[2] == str(sid)]
            return np.sort(np.concatenate(ts)) if ts else np.zeros(0, np.int64)
        return self.times.get(f"larns/station/{sid}/{what}", np.zeros(0, np.int64))

    def from_station(self, sid: int) -> np.ndarray:
        """Log times of every message station ``sid`` sent (any of its keys)."""
        ts = [t for k, t in self.times.items() if k.startswith(f"larns/station/{sid}/")]
        return np.sort(np.concatenate(ts)) if ts else np.zeros(0, np.int64)

    def replies(self, frm: list[int], to: list[int]) -> np.ndarray:
        """Log times of the range replies of stations ``frm`` to stations ``to``."""
        ts = [self.of(i, f"range/rsp/{j}") for i in frm for j in to]
        return np.sort(np.concatenate(ts))


@dataclass
class SitesRun:
    scenario: Path
    epoch: float
    events: dict[str, float] = field(default_factory=dict)       # name -> wall time (Unix s)
    networks: dict[str, set] = field(default_factory=dict)       # service -> its networks (no project prefix)
    rec: dict[str, Recording] = field(default_factory=dict)      # site -> its recorder's file
    recorder_rc: dict[str, int | None] = field(default_factory=dict)
    down_rc: int | None = None

    def ns(self, event: str) -> int:
        return int(self.events[event] * 1e9)

    def fleet_t(self, event: str) -> float:
        return (self.events[event] - self.epoch) * SPEED


@pytest.fixture(scope="module")
def sites():
    image = larns_image()
    tmp = Path(tempfile.mkdtemp(prefix="larns-sites-"))
    try:
        yield _timeline(image, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _timeline(image: str, tmp: Path) -> SitesRun:
    """Run the module docstring's timeline once; ``down -v`` at the end, always."""
    scn, compose_file = tmp / "sites.toml", tmp / "sites.yml"
    scn.write_text(SCENARIO)
    tmp.chmod(0o755)                  # the containers run as an unprivileged user
    scn.chmod(0o644)
    g = run([sys.executable, str(ROOT / "scripts/compose-sites.py"), "--site-a", "1-5", "--site-b", "6-10",
             "--out", str(compose_file)])
    assert g.returncode == 0, g.stderr
    runs = ROOT / "runs"
    runs.mkdir(exist_ok=True)
    mcaps = {s: runs / f"{NAME}-{s}.mcap" for s in SITES}
    logs = runs / f"{NAME}.log"
    for f in [*mcaps.values(), logs]:
        f.unlink(missing_ok=True)
    epoch = float(int(time.time()) + 5)
    env = {**os.environ, "LARNS_IMAGE": image, "LARNS_SCENARIO": "sites", "LARNS_SCENARIO_DIR": str(tmp),
           "LARNS_SPEED": repr(SPEED), "LARNS_EPOCH": repr(epoch), "LARNS_RUN": NAME, "LARNS_RUNS_DIR": str(runs),
           "LARNS_UID": str(os.getuid()), "LARNS_GID": str(os.getgid())}
    dc = Compose(COMPOSE, f"larnssites{os.getpid()}", env, compose_file)
    out = SitesRun(scenario=scn, epoch=epoch)
    backbone = f"{dc.project}_backbone"
    try:
        t0 = time.time()
        dc("up", "-d", timeout=240)
        cids = {svc: c for svc, (c, _st) in dc.containers().items()}
        for svc in [s for s in cids if s.startswith(("station", "router", "recorder"))]:
            nets = run(["docker", "inspect", "-f", "{{range $k, $v := .NetworkSettings.Networks}}{{$k}} {{end}}",
                        cids[svc]]).stdout.split()
            out.networks[svc] = {n.removeprefix(f"{dc.project}_") for n in nets}
        waiting = wait_started({i: cids[f"station{i}"] for s in SITES.values() for i in s}, t0)
        assert not waiting, f"stations {sorted(waiting)} did not start within 120 s"
        out.events["running"] = start = max(time.time(), epoch)
        print(f"[sites] all stations running after {start - t0:.1f} s", file=sys.stderr)

        sleep_until(start + CONVERGE_WALL_S)
        st = dc.containers()
        down = [svc for svc in cids if svc not in ("epoch", "keys") and st.get(svc, ("", ""))[1] != "running"]
        assert not down, f"containers not running: {down}"
        out.events["cut"] = time.time()
        for r in ("router_a", "router_b"):
            c = run(["docker", "network", "disconnect", backbone, cids[r]])
            assert c.returncode == 0, c.stderr
        sleep_until(out.events["cut"] + CUT_WALL_S)
        out.events["heal"] = time.time()
        for r in ("router_a", "router_b"):
            c = run(["docker", "network", "connect", "--alias", r, backbone, cids[r]])
            assert c.returncode == 0, c.stderr
        out.events["healed"] = time.time()
        sleep_until(out.events["heal"] + RUN_ON_WALL_S)

        logs.write_text(dc("logs", "--no-color", check=False).stdout)
        waits: dict[str, str] = {}

        def wait(site: str) -> None:     # a recorder's exit code, caught before `down` removes it
            waits[site] = run(["docker", "wait", cids[f"recorder_{site}"]], timeout=60).stdout.strip()

        threads = [threading.Thread(target=wait, args=(s,)) for s in SITES]
        for th in threads:
            th.start()
        out.events["down"] = time.time()
        out.down_rc = dc("down", "-v", timeout=120, check=False).returncode
        for th in threads:
            th.join(60)
        for s in SITES:
            rc = waits.get(s, "").splitlines()
            out.recorder_rc[s] = int(rc[-1]) if rc and rc[-1].lstrip("-").isdigit() else None
        print(f"[sites] timeline {time.time() - t0:.1f} s wall; recorders exit {out.recorder_rc}", file=sys.stderr)
        for s, p in mcaps.items():
            assert p.exists(), f"no MCAP from recorder_{s}; logs: {logs}"
            out.rec[s] = Recording.read(p)
        return out
    finally:
        logs_and_down(dc, logs, "sites")


def _gaps(t_ns: np.ndarray, t0_ns: int, t1_ns: int) -> float:
    """The longest silence (wall s) in log times ``t_ns`` over [t0, t1], its ends included."""
    w = np.concatenate([[t0_ns], t_ns[(t_ns > t0_ns) & (t_ns < t1_ns)], [t1_ns]])
    return float(np.diff(w).max() / 1e9)


# -------------------------------------------------------------------------------------------- tests

def test_stations_reach_only_their_sites_router(sites):
    for site, ids in SITES.items():
        for i in ids:
            assert sites.networks[f"station{i}"] == {f"site_{site}"}, (i, sites.networks[f"station{i}"])
        assert sites.networks[f"recorder_{site}"] == {f"site_{site}"}
        assert sites.networks[f"router_{site}"] == {f"site_{site}", "backbone"}
    # secure by default: every nav in both recordings is a signed frame
    assert [r.unsigned_navs for r in sites.rec.values()] == [0, 0]


def test_one_field_before_the_cut(sites):
    """Both recorders hear all 10 stations, ranges cross the backbone both ways, the survey converged."""
    t_cut = sites.ns("cut")
    for site, rec in sites.rec.items():
        for i in SITES["a"] + SITES["b"]:
            assert (rec.of(i) < t_cut).sum() >= 20, (site, i, "too few navs before the cut")
        assert (rec.replies(SITES["a"], SITES["b"]) < t_cut).sum() > 0, site
        assert (rec.replies(SITES["b"], SITES["a"]) < t_cut).sum() > 0, site
    summ = sites.rec["a"].summary
    ids = [i for i in SITES["a"] + SITES["b"] if i != 1]             # station 1 is the fixed origin
    errs, sigs = np.array([err_sigma(summ[i], at_index(summ[i], t_cut)) for i in ids]).T
    t0 = sites.fleet_t("running")
    sim = sim_rms(sites.scenario, sites.fleet_t("cut") - t0, ids, {}, {})
    rms = float(np.sqrt(np.mean(errs ** 2)))
    print(f"before the cut: RMS {rms:.2f} m vs simulator {sim:.2f} m")
    assert rms <= 3.0 * sim + 1.0, (rms, sim, dict(zip(ids, errs)))
    assert np.all(errs <= 4.0 * sigs + 0.5), dict(zip(ids, zip(errs, sigs)))
    assert np.all(sigs < 10.0), sigs


def test_the_cut_splits_the_field(sites):
    """While the backbone is cut, nothing of the other site reaches a site (its router, its recorder)."""
    t0, t1 = sites.ns("cut") + int(GRACE_S * 1e9), sites.ns("heal")
    for site, rec in sites.rec.items():
        other = SITES["b" if site == "a" else "a"]
        leaked = {i: int(((rec.from_station(i) > t0) & (rec.from_station(i) < t1)).sum()) for i in other}
        assert not any(leaked.values()), (site, "messages from the other site during the cut", leaked)


def test_each_site_keeps_surveying_through_the_cut(sites):
    """From each site's own recorder: its stations keep publishing navs and estimates without a pause,
    keep updating their survey, and stay within their uncertainty of the truth."""
    t_cut, t_heal = sites.ns("cut"), sites.ns("heal")
    for site, ids in SITES.items():
        rec = sites.rec[site]
        navs = {i: int(((rec.of(i) > t_cut) & (rec.of(i) < t_heal)).sum()) for i in ids}
        pauses = {i: round(_gaps(rec.of(i), t_cut - int(1e9), t_heal), 1) for i in ids}
        print(f"site {site} during the {CUT_WALL_S:.0f} s cut: navs {navs}, longest pause s {pauses}")
        expected = CUT_WALL_S * SPEED / CYCLE_S                      # one nav per cycle
        assert all(n >= 0.7 * expected for n in navs.values()), (site, navs, expected)
        assert all(p <= PAUSE_S for p in pauses.values()), (site, pauses)
        for i in ids:
            s = rec.summary[i]
            b, e = at_index(s, t_cut), at_index(s, t_heal)
            assert _gaps(s["log_time_ns"], t_cut - int(1e9), t_heal) <= PAUSE_S, (site, i, "estimates paused")
            if i == 1:
                continue                                               # the fixed origin does not update
            assert s["n_updates"][e] - s["n_updates"][b] >= 0.5 * expected, (site, i, s["n_updates"][b],
                                                                               s["n_updates"][e])
            err, sig = err_sigma(s, e)
            assert err <= 4.0 * sig + 0.5, (site, i, err, sig)
            assert sig < 10.0, (site, i, sig)


def test_sites_merge_again_after_the_heal(sites):
    """Each recorder hears the other site again within MERGE_S of the heal, ranges between the sites
    resume, the navs list the other site's stations as members again, nobody moves by more than
    1 sigma when the other site comes back, and the whole field is consistent at the end."""
    t_heal, t_down = sites.ns("heal"), sites.ns("down")
    back: dict[str, float] = {}
    for site, rec in sites.rec.items():
        mine, other = SITES[site], SITES["b" if site == "a" else "a"]
        for i in other:
            t = rec.of(i)
            after = t[t > t_heal]
            assert len(after), (site, i, "never heard again after the heal")
            back[f"{i}@{site}"] = round(float(after[0] - t_heal) / 1e9, 2)
            assert _gaps(t, int(after[0]), t_down - int(2e9)) <= PAUSE_S, (site, i, "heard again, then silent")
        assert (rec.replies(other, mine) > t_heal).sum() > 0, (site, "no range reply from the other site")
        assert (rec.replies(mine, other) > t_heal).sum() > 0, (site, "no range reply to the other site")
        # the last 5 s before `down` (once it starts, stations stop one by one and leave the lists):
        # each station lists the whole other site in nearly every nav. Not in every one: a station
        # whose process or router stalls for 5 cycles (0.6 s of wall at speed 5) lists only the few
        # peers it heard in the horizon, its own site's as well, until it catches up
        for i in mine:
            late = [m for t, m in rec.members[i] if t_down - int(5e9) < t <= t_down]
            whole = [set(other) <= set(m) for m in late]
            assert late and sum(whole) >= WHOLE_SHARE * len(late), (site, i, f"{sum(whole)} of {len(late)}",
                                                                    [m for m, w in zip(late, whole) if not w][-3:])
        # the other site's navs back in the solves do not shake this site's estimates
        t_back = int(min(rec.of(i)[rec.of(i) > t_heal][0] for i in other))
        assert_not_disturbed(rec.summary, t_back, [i for i in mine if i != 1], 2 * CYCLE_S / SPEED)
    print(f"first nav of the other site after the heal, s: {dict(sorted(back.items(), key=lambda kv: kv[1]))}")
    assert max(back.values()) <= MERGE_S, back
    for site, rec in sites.rec.items():
        for i in [i for i in SITES["a"] + SITES["b"] if i != 1]:
            s = rec.summary[i]
            err, sig = err_sigma(s, len(s["log_time_ns"]) - 1)
            assert err <= 4.0 * sig + 0.5, (site, i, err, sig)
            assert s["log_time_ns"][-1] >= t_down - int(3e9), (site, i, "no estimate near the end")


def test_both_recordings_complete(sites):
    from larns.log import read_log

    assert sites.down_rc == 0
    assert sites.recorder_rc == {"a": 0, "b": 0}, sites.recorder_rc
    for site, rec in sites.rec.items():
        log = read_log(rec.path)
        assert log.complete, (site, log.error)
        last = max(m.log_time for m in log.messages)
        assert last >= sites.ns("down") - int(3e9), (site, last / 1e9, sites.events["down"])
