#!/usr/bin/env python3
"""Write a compose file for a LARNS field split over two sites, each on its own Docker network with
its own Zenoh router, the routers linked over a third network, the "backbone" (docs/deploy.md,
"Two sites, a router each").

    scripts/compose-sites.py --out runs/sites.yml                      # stations 1-5 | 6-10
    scripts/compose-sites.py --site-a 1-4,9 --site-b 5-8,10 --out sites.yml
    docker compose -f runs/sites.yml --project-directory . -p sites up -d   # (or docker-compose v1)
    docker network disconnect sites_backbone sites_router_b_1          # cut the backbone ...
    docker network connect --alias router_b sites_backbone sites_router_b_1   # ... and heal it

(``--project-directory .``: the file's relative paths, ``./net/scenarios`` and ``./runs``, are the
repository's, not the folder the file is written to.)

Services (the same image, epoch and keystore conventions as docker-compose.yml):

* ``router_a`` on networks ``site_a`` and ``backbone``, ``router_b`` on ``site_b`` and ``backbone``;
  ``router_b`` connects to ``router_a`` over the backbone (and keeps retrying while it is cut);
  both are ``larns router`` (Zenoh router mode);
* ``station<N>`` on its site's network only, a Zenoh client of its site's router
  (``--zenoh-mode client --connect tcp/router_<site>:7447``): it cannot reach the other site;
* ``recorder_a`` / ``recorder_b``, one per site (each records what reaches its site's router:
  both sites while the backbone is up, its own site alone while it is cut) into
  ``<LARNS_RUNS_DIR>/<LARNS_RUN>-a.mcap`` and ``-b.mcap``;
* ``epoch`` and ``keys``, one-shot, as in docker-compose.yml: one fleet epoch, one keystore (the
  two routers share the enclave ``router``, the two recorders ``recorder``), each service's part
  exported into its own volume ``keys-<service>``; secure by default (``LARNS_SECURE=`` empty:
  plain tcp). Every ``tcp/`` endpoint below becomes ``tls/`` under ``--secure``.

Variables: those of docker-compose.yml (``LARNS_IMAGE``, ``LARNS_SCENARIO``, ``LARNS_SCENARIO_DIR``,
``LARNS_SPEED``, ``LARNS_EPOCH``, ``LARNS_RUN``, ``LARNS_UID``/``LARNS_GID``, ``LARNS_SECURE``), and
``LARNS_RUNS_DIR`` (default ``./runs`` next to the written file) for the recordings.

The output is JSON, which is YAML: compose (v2 plugin, or docker-compose v1 >= 1.29) reads it.
Standard library only; any Python >= 3.8.
"""

from __future__ import annotations

import argparse
import json
import sys

SITES = ("a", "b")
SCENARIO_FILE = "/scenarios/${LARNS_SCENARIO:-seed000}.toml"
PORT = 7447


def parse_ids(spec: str) -> list[int]:
    """``"1-5,9"`` -> [1, 2, 3, 4, 5, 9]."""
    out: list[int] = []
    for part in filter(None, (p.strip() for p in spec.split(","))):
        lo, _, hi = part.partition("-")
        out += range(int(lo), int(hi or lo) + 1)
    return out


def _entrypoint(epoch: bool) -> list[str]:
    """``larns "$@" [--epoch <fleet epoch>] --speed K [--secure <keystore>]``, as docker-compose.yml."""
    ep = ' --epoch "$$(cat /fleet/epoch)"' if epoch else ""
    return ["/bin/sh", "-c",
            f'exec larns "$$@"{ep} --speed "$${{LARNS_SPEED:-1}}" $${{LARNS_SECURE:+--secure "$$LARNS_SECURE"}}',
            "larns"]


def _service(name: str, networks: list[str], command: list[str], epoch: bool = True) -> dict:
    """A larns process: its networks, its own keys volume at /keys, the scenarios, the epoch."""
    return {
        "image": "${LARNS_IMAGE:-larns:latest}", "init": True, "networks": networks,
        "volumes": ["${LARNS_SCENARIO_DIR:-./net/scenarios}:/scenarios:ro", f"keys-{name}:/keys:ro"],
        "volumes_from": ["epoch:ro"],
        "depends_on": {"epoch": {"condition": "service_completed_successfully"},
                       "keys": {"condition": "service_completed_successfully"}},
        "environment": {"LARNS_SPEED": "${LARNS_SPEED:-1}", "LARNS_SECURE": "${LARNS_SECURE-/keys}"},
        "entrypoint": _entrypoint(epoch), "command": command, "stop_grace_period": "10s",
        # a dead TCP peer (a cut network) fails after ~6 s, before Zenoh's 10 s lease (docs/deploy.md)
        "sysctls": {"net.ipv4.tcp_retries2": 4},
    }


def _keys_script(enclaves: dict[str, str], station_ids: list[int]) -> str:
    """The one-shot `keys` service: the keystore once, then each service's part into its volume."""
    lines = ['if [ $$# -gt 0 ]; then larns keys "$$@" || exit 1',
             'elif [ ! -s /keys/keystore.json ]; then',
             f'  larns keys init /keys --stations {",".join(map(str, station_ids))} || exit 1',
             'fi',
             'chown -R 0:0 /keys && chmod 700 /keys']
    for svc, cn in enclaves.items():
        owner = "$${LARNS_UID}:$${LARNS_GID}" if cn == "recorder" else "10001:10001"
        lines += [f'larns keys export /keys /hosts/{svc} --enclave {cn} 2>/dev/null || exit 1',
                  f'chown -R "{owner}" /hosts/{svc} && chmod 700 /hosts/{svc}']
    lines.append('echo "keystore /keys exported to $$(ls /hosts | tr \'\\n\' \' \')"')
    return "\n".join(lines) + "\n"


def sites_compose(site_a: list[int], site_b: list[int]) -> dict:
    """The compose document (a dict) for stations ``site_a`` on site A and ``site_b`` on site B."""
    both = set(site_a) & set(site_b)
    if both:
        raise ValueError(f"stations on both sites: {sorted(both)}")
    if not site_a or not site_b:
        raise ValueError("each site needs at least one station")
    services: dict[str, dict] = {}
    enclaves: dict[str, str] = {}
    for site, ids in zip(SITES, (site_a, site_b)):
        router, net = f"router_{site}", f"site_{site}"
        cmd = ["router", "--listen", f"tcp/0.0.0.0:{PORT}", "--scenario", SCENARIO_FILE]
        if site == "b":       # one link over the backbone, dialled (and redialled) from site B
            cmd += ["--connect", f"tcp/router_a:{PORT}"]
        services[router] = _service(router, [net, "backbone"], cmd, epoch=False)
        enclaves[router] = "router"
        client = ["--zenoh-mode", "client", "--connect", f"tcp/{router}:{PORT}"]
        for i in ids:
            services[f"station{i}"] = _service(f"station{i}", [net], [
                "station", "--id", str(i), "--scenario", SCENARIO_FILE, *client])
            enclaves[f"station{i}"] = f"station-{i}"
        rec = f"recorder_{site}"
        services[rec] = _service(rec, [net], [
            "record", "-o", f"/runs/${{LARNS_RUN:-sites}}-{site}.mcap", "--scenario", SCENARIO_FILE,
            *client])
        services[rec]["user"] = "${LARNS_UID:-0}:${LARNS_GID:-0}"
        services[rec]["volumes"].append("${LARNS_RUNS_DIR:-./runs}:/runs")
        enclaves[rec] = "recorder"
    one_shot = {"image": "${LARNS_IMAGE:-larns:latest}", "user": "0:0", "network_mode": "none",
                "healthcheck": {"disable": True}}
    epoch = {**one_shot, "volumes": ["/fleet"], "environment": {"LARNS_EPOCH": "${LARNS_EPOCH:-}"},
             "entrypoint": ["/bin/sh", "-c",
                            '[ -s /fleet/epoch ] || echo "$${LARNS_EPOCH:-$$(date +%s)}" >/fleet/epoch\n'
                            'chmod 644 /fleet/epoch\necho "fleet epoch $$(cat /fleet/epoch) (Unix s)"\n']}
    keys = {**one_shot, "volumes": ["keystore:/keys", *(f"keys-{s}:/hosts/{s}" for s in enclaves)],
            "environment": {"LARNS_UID": "${LARNS_UID:-0}", "LARNS_GID": "${LARNS_GID:-0}"},
            "entrypoint": ["/bin/sh", "-c", _keys_script(enclaves, sorted(site_a + site_b)), "keys"]}
    return {"services": {"epoch": epoch, "keys": keys, **services},
            "networks": {n: {"driver": "bridge"} for n in ("site_a", "site_b", "backbone")},
            "volumes": {"keystore": {}, **{f"keys-{s}": {} for s in enclaves}}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--site-a", default="1-5", metavar="IDS", help="stations of site A (default 1-5)")
    ap.add_argument("--site-b", default="6-10", metavar="IDS", help="stations of site B (default 6-10)")
    ap.add_argument("--out", "-o", default="-", metavar="FILE", help="compose file to write (default stdout)")
    a = ap.parse_args(argv)
    try:
        doc = sites_compose(parse_ids(a.site_a), parse_ids(a.site_b))
    except ValueError as e:
        ap.error(str(e))
    text = ("# LARNS on two sites; written by scripts/compose-sites.py (JSON is YAML)\n"
            + json.dumps(doc, indent=1) + "\n")
    for site, ids in zip(SITES, (a.site_a, a.site_b)):
        if len(parse_ids(ids)) < 4:
            print(f"compose-sites.py: warning: site {site.upper()} has fewer than 4 stations: while the backbone "
                  "is cut each ranges to fewer than 3 live peers (tested: 5 a site, docs/deploy.md)", file=sys.stderr)
    if a.out == "-":
        sys.stdout.write(text)
    else:
        with open(a.out, "w") as f:
            f.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
