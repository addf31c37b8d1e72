"""`larns reestimate run.mcap`: re-run the stations' (and aircraft's) estimators on a recording,
offline (no Zenoh, no sleeping) - the same as ``larns replay --offline run.mcap``, which stays."""

from __future__ import annotations



def register(sub) -> None:
    from .helptext import Formatter, examples

    from .replay import add_offline_args, cmd_offline

    p = sub.add_parser(
        "reestimate", help="re-run the estimators on a recording offline (= replay --offline)",
        description="Every station with a recorded core journal is rebuilt and re-run; re-running the recorded "
                    "estimator reproduces the recorded estimates bit for bit (checked and reported). "
                    "--estimator runs another survey estimator on the same inputs, --algo re-runs the aircraft "
                    "estimators on the recorded nav broadcasts, -o writes the recording with the estimates "
                    "replaced. Same as `larns replay --offline` (docs/replay.md).",
        formatter_class=Formatter, epilog=examples(
            "larns reestimate runs/demo.mcap",
            "larns reestimate runs/demo.mcap --estimator seed-ukf -o runs/demo-ukf.mcap",
        ))
    p.add_argument("files", nargs="+", help="MCAP file(s), merged by log time")
    add_offline_args(p)
    p.add_argument("--json", action="store_true", help="print statistics as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_offline, offline=True)


