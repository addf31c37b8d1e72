"""``larns fleet`` on a protocol-v2 scenario (``[tdma] ranging = "poll"``, simulator only in issue 31's
first phase): one line naming the key, exit code 2, nothing started."""

from __future__ import annotations

import pytest
from scenario_text import five_stations

from larns.cli import build_parser
from larns.fleet.plan import plan_fleet


def test_a_fleet_refuses_the_poll_with_one_line(tmp_path, capsys):
    scn = tmp_path / "p.toml"
    scn.write_text(five_stations("p", 1).replace("slot_s = 0.05\n", 'slot_s = 0.05\nranging = "poll"\n'))
    args = build_parser().parse_args(["fleet", "--scenario", str(scn), "--logs", str(tmp_path / "logs")])
    with pytest.raises(SystemExit) as e:
        plan_fleet(args)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and '[tdma] ranging: "poll"' in err[0] and str(scn) in err[0], err
    assert not (tmp_path / "logs").exists()  # nothing started
    # the same field with the addressed exchange plans a fleet
    scn.write_text(five_stations("p", 1))
    assert plan_fleet(args).children
