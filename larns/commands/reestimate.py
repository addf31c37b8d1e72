"""`larns reestimate run.mcap`: re-run the stations', aircraft's and vehicles' estimators on a recording,
offline (no Zenoh, no sleeping) - the same as ``larns replay --offline run.mcap``, which stays."""

from __future__ import annotations



def register(sub) -> None:
    from .helptext import Formatter, examples

    from .replay import add_offline_args, cmd_offline

    p = sub.add_parser(
        "reestimate", help="re-run the estimators on a recording offline (= replay --offline)",
        description="Every station, aircraft and vehicle with a recorded journal is rebuilt and re-run; re-running "
                    "the recorded estimator or algorithm reproduces the recorded estimates bit for bit (checked and "
                    "reported; --check exits 3 otherwise). --estimator runs another survey estimator on the same "
                    "inputs, --algo another aircraft algorithm on the aircraft's journal; each prints its accuracy "
                    "against the recorded truth (RMS error / mean sigma) beside the recorded one's. -o writes the "
                    "recording with the estimates replaced. Same as `larns replay --offline` (docs/replay.md).",
        formatter_class=Formatter, epilog=examples(
            "larns reestimate runs/demo.mcap",
            "larns reestimate runs/demo.mcap --estimator seed-ukf -o runs/demo-ukf.mcap",
            "larns reestimate runs/demo.mcap --algo ekf-pr --algo ukf-tdoa --check",
        ))
    p.add_argument("files", nargs="+", help="MCAP file(s), merged by log time")
    add_offline_args(p)
    p.add_argument("--json", action="store_true", help="print statistics as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_offline, offline=True)


