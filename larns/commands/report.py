"""`larns report run.mcap -o DIR`: figures and a Markdown summary (:mod:`larns.viz.report`)."""

from __future__ import annotations

import argparse
import sys


def cmd_report(args: argparse.Namespace) -> int:
    from larns.viz.report import make_report

    try:
        res = make_report(args.files, args.output, scenario=args.scenario, sigma_m=args.sigma)
    except (OSError, ValueError) as e:
        print(f"larns report: {e}", file=sys.stderr)
        return 1
    print(f"[report] {len(res['figures'])} figures + report.md in {args.output}", file=sys.stderr)
    return 0


def register(sub) -> None:
    from .helptext import Formatter, examples

    from . import doc_of

    p = sub.add_parser("report", help="PNG figures and a Markdown summary of a recording",
                       description=doc_of("larns.viz.report"), formatter_class=Formatter,
                       epilog=examples(
                           "larns report runs/demo.mcap -o runs/report",
                       ))
    p.add_argument("files", nargs="+", help="MCAP recording(s), merged by log time")
    p.add_argument("-o", "--output", default="report", help="output folder (default ./report)")
    p.add_argument("--scenario", default=None, help="scenario (for the aircraft's ranging sigma in the CRLB); "
                                                    "default: the recording's metadata")
    p.add_argument("--sigma", type=float, default=None, help="aircraft ranging sigma for the CRLB, m")
    p.set_defaults(func=cmd_report)
