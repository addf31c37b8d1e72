"""The live Foxglove view's pure core (:class:`larns.viz.live.LiveView`), the SDK's typed messages it
sends (decoded back by their own protobuf schema), and the real SDK server with a protocol client."""

from __future__ import annotations

import asyncio
import json

import jsonschema
import pytest

from foxglove_ws import FoxgloveClient, ProtoSchema
from net import messages as M

from larns.viz.sdk_schema import json_schema
from larns.viz.live import LIVE_SCHEMAS, LOG_TOPIC, SCHEMA_BYTES, TDMA_TOPIC, FoxgloveServer, LiveView, to_sdk

I3 = [[1.0, 0.0, 0.0], [0.0, 4.0, 0.0], [0.0, 0.0, 9.0]]


def _est(sid, t, pos, **kw):
    m = {"kind": "estimate", "src": sid, "seq": int(t * 10), "stamp_s": t, "t_s": t, "pos_m": pos, "cov_m2": I3,
         "n_updates": 3, "estimator": "dmap", "state": "surveying", **kw}
    return M.key_for(m), M.encode(m)


def _truth(sid, t, pos, **kw):
    m = {"kind": "truth", "src": sid, "seq": int(t * 10), "stamp_s": t, "t_s": t, "pos_m": pos, **kw}
    return M.key_for(m), M.encode(m)


def test_malformed_samples_are_counted_by_reason_and_logged_never_raised():
    v = LiveView()
    key, good = _est(2, 1.0, [1.0, 2.0, 3.0])
    bad = [b"junk", b"", M.encode({"kind": "truth", "src": 2, "seq": 0, "stamp_s": 0.0, "t_s": 0.0,
                                   "pos_m": [0.0, 0.0, 0.0]})[:-3], b"\x81\xa1v\x02"]
    outs = [v.on_sample("larns/station/2/nav", b) for b in bad]
    assert sum(v.dropped.values()) == 4 and v.dropped["version"] == 1
    assert all(len(o) <= 1 for o in outs)
    first = [o[0] for o in outs if o]
    assert first and all(o.topic == LOG_TOPIC and "dropped malformed" in o.data["message"] for o in first)
    # a valid message afterwards is still converted
    topics = {o.topic for o in v.on_sample(key, good)}
    assert "larns/foxglove/station/2" in topics and v.t_ns == 1_000_000_000
    # the 100th drop of one reason is logged again, the 99 between are silent
    n_logs = sum(len(v.on_sample("k", b"junk")) for _ in range(200))
    assert v.dropped["msgpack"] == 203 and n_logs == 2  # junk, empty, truncated + 200


def test_sync_record_joins_estimate_and_truth_of_the_same_stamp_in_either_order():
    v = LiveView()
    v.on_sample(*_est(3, 2.0, [5.0, 0.0, 0.0], clock_offset_s=3e-6, clock_offset_sd_s=1e-7))
    (o,) = [o for o in v.on_sample(*_truth(3, 2.0, [5.0, 0.0, 0.0], clock_error_s=2.5e-6))
            if o.topic.endswith("/sync")]
    assert o.data["sync_err_s"] == pytest.approx(0.5e-6) and o.log_ns == 2_000_000_000
    v.on_sample(*_truth(3, 3.0, [5.0, 0.0, 0.0], clock_error_s=1e-6))
    (o,) = [o for o in v.on_sample(*_est(3, 3.0, [5.0, 0.0, 0.0], clock_offset_s=0.0)) if o.topic.endswith("/sync")]
    assert o.data["sync_err_s"] == pytest.approx(-1e-6)
    jsonschema.validate(o.data, LIVE_SCHEMAS["larns.StationSync"])


def test_exchange_is_a_timeline_record_and_a_line_between_the_stations():
    v = LiveView()
    req = {"kind": "range_req", "src": 1, "seq": 5, "stamp_s": 4.0, "dst": 2, "cycle": 4, "slot": 0, "t_tx_s": 4.0}
    (o,) = v.on_sample(M.key_for(req), M.encode(req))
    assert o.topic == TDMA_TOPIC and o.data == {"t_s": 4.0, "cycle": 4, "slot": 0, "src": 1, "dst": 2}
    v.on_sample(*_est(1, 4.0, [0.0, 0.0, 0.0]))
    v.on_sample(*_est(2, 4.0, [100.0, 0.0, 0.0]))
    outs = v.on_sample(M.key_for(req), M.encode(req))
    (line,) = [o.data["entities"][0]["lines"][0] for o in outs if o.topic == "larns/foxglove/scene"]
    assert [p["x"] for p in line["points"]] == [0.0, 100.0]


def test_integrity_decisions_and_liveliness_are_logs():
    v = LiveView()
    m = {"kind": "integrity", "src": 4, "seq": 1, "stamp_s": 9.0, "t_s": 9.0, "suspect": 5, "statistic": 20.0,
         "threshold": 10.83, "dof": 1, "p_fa": 0.001, "decision": "exclude"}
    (o,) = v.on_sample(M.key_for(m), M.encode(m))
    assert o.topic == LOG_TOPIC and o.data["level"] == 3 and "station 4 excludes station 5" in o.data["message"]
    (o,) = v.on_alive("larns/alive/aircraft/ac1", False)
    assert o.data["message"] == "aircraft/ac1 went away" and o.log_ns == 9_000_000_000


def test_tracks_and_typed_messages_decode_back_by_their_own_schema():
    v = LiveView()
    outs = []
    for i in range(4):
        m = {"kind": "ac_estimate", "src": "ac1", "seq": i, "stamp_s": float(i), "t_s": float(i),
             "pos_m": [float(i), 2.0, 300.0], "cov_m2": I3, "algo": "ukf-pr"}
        outs += v.on_sample(M.key_for(m), M.encode(m))
    outs += v.on_sample(*_truth(1, 5.0, [0.0, 0.0, 0.0]))
    outs += v.on_sample(*_est(1, 5.0, [0.0, 0.0, 0.0]))
    outs += v.on_alive("larns/alive/station/1", True)
    tracks = [o for o in outs if o.topic == "larns/foxglove/scene"
              and o.data["entities"][0]["id"] == "aircraft/ac1/ukf-pr/track"]
    assert len(tracks[-1].data["entities"][0]["lines"][0]["points"]) == 4
    kinds = set()
    for o in outs:
        if o.schema.startswith("foxglove."):
            jsonschema.validate(o.data, json_schema(o.schema))  # the recorder's JSON form, same definition
            msg = to_sdk(o.schema, o.data)
            schema = type(msg).get_schema()
            assert schema.encoding == "protobuf"
            back = ProtoSchema(schema.data).decode(o.schema, msg.encode())
            kinds.add(o.schema)
            if o.schema == "foxglove.FrameTransform":
                assert back["child_frame_id"] == o.data["child_frame_id"]
                assert back["translation"].get("x", 0.0) == o.data["translation"]["x"]
            elif o.schema == "foxglove.SceneUpdate":
                ent = back["entities"][0]
                assert ent["id"] == o.data["entities"][0]["id"]
                if o.data["entities"][0]["lines"]:
                    assert len(ent["lines"][0]["points"]) == len(o.data["entities"][0]["lines"][0]["points"])
            else:
                assert back["message"] == o.data["message"]
        else:
            schema = json.loads({**SCHEMA_BYTES}.get(o.schema, b"null")) or LIVE_SCHEMAS[o.schema]
            jsonschema.validate(o.data, schema)
    assert kinds == {"foxglove.FrameTransform", "foxglove.SceneUpdate", "foxglove.Log"}


@pytest.mark.e2e  # a real WebSocket client timed against the server (subscriptions within 0.5 s): alone
def test_server_sends_what_the_view_makes_to_a_protocol_client():
    srv = FoxgloveServer(port=0)
    v = LiveView()
    try:
        async def go():
            async with FoxgloveClient(f"ws://127.0.0.1:{srv.port}") as c:
                await c.run(0.3)
                srv.send(v.on_sample(*_est(2, 7.5, [1.0, 2.0, 3.0])))
                await c.run(0.5)   # advertise -> subscribe
                srv.send(v.on_sample(*_est(2, 8.0, [1.0, 2.0, 3.0])))
                srv.send(v.on_sample("larns/station/2/nav", b"\xc1junk"))
                srv.time(v.t_ns)
                return await c.run(3.0, until=lambda g: g.of(LOG_TOPIC) and g.times_ns)

        got = asyncio.run(go())
    finally:
        srv.stop()
    assert got.undecodable == []
    assert [m["t_s"] for m in got.of("larns/foxglove/station/2")] == [8.0]
    assert "dropped malformed" in got.of(LOG_TOPIC)[0]["message"]
    assert got.times_ns[-1] == 8_000_000_000
    assert srv.failed == {}


def test_station_drop_counts_and_aircraft_states_are_logged_on_change():
    v = LiveView()
    assert not [o for o in v.on_sample(*_est(2, 1.0, [0.0, 0.0, 0.0], dropped=0)) if o.topic == LOG_TOPIC]
    (o,) = [o for o in v.on_sample(*_est(2, 2.0, [0.0, 0.0, 0.0], dropped=3)) if o.topic == LOG_TOPIC]
    assert o.data["message"] == "station 2 dropped 3 malformed message(s) (3 so far)" and o.data["level"] == 3
    assert not [o for o in v.on_sample(*_est(2, 3.0, [0.0, 0.0, 0.0], dropped=3)) if o.topic == LOG_TOPIC]
    logs = []
    for i, state in enumerate(["waiting", "waiting", "tracking"]):
        m = {"kind": "ac_status", "src": "ac1", "seq": i, "stamp_s": float(i), "t_s": float(i), "algo": "ukf-pr",
             "state": state}
        logs += [o.data["message"] for o in v.on_sample(M.key_for(m), M.encode(m))]
    assert logs == ["ac1 ukf-pr: waiting", "ac1 ukf-pr: tracking"]


def test_fleet_view_adds_a_viewer_child(tmp_path):
    from scenario_text import five_stations

    from larns.cli import build_parser
    from larns.fleet.plan import plan_fleet

    scn = tmp_path / "v.toml"
    scn.write_text(five_stations("v", 1))
    args = build_parser().parse_args(["fleet", "--scenario", str(scn), "--view", "--logs", str(tmp_path)])
    (viewer,) = [c for c in plan_fleet(args).children if c.name == "viewer"]
    i = viewer.cmd.index("view")
    assert viewer.cmd[i + 1:i + 3] == ["--port", "8765"] and "--connect" in viewer.cmd
    assert viewer.log_path == tmp_path / "viewer.log"
    args = build_parser().parse_args(["fleet", "--scenario", str(scn)])
    assert not [c for c in plan_fleet(args).children if c.name == "viewer"]


def test_json_schemas_generated_from_the_sdk_reject_what_the_sdk_would_not_encode():
    tf = {"timestamp": {"sec": 1, "nsec": 5}, "parent_frame_id": "network", "child_frame_id": "station_2",
          "translation": {"x": 1.0, "y": 2.0, "z": 3.0}, "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}
    jsonschema.validate(tf, json_schema("foxglove.FrameTransform"))
    for bad in ({k: v for k, v in tf.items() if k != "child_frame_id"},
                {**tf, "timestamp": {"sec": 1, "nsec": 1_000_000_000}},
                {**tf, "translation": {"x": "1", "y": 2.0, "z": 3.0}}):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(bad, json_schema("foxglove.FrameTransform"))
    scene = json_schema("foxglove.SceneUpdate")
    ent = scene["properties"]["entities"]["items"]
    assert ent["properties"]["lifetime"]["required"] == ["sec", "nsec"]
    assert ent["properties"]["lines"]["items"]["properties"]["points"]["items"]["title"] == "foxglove.Point3"
    assert set(json_schema("foxglove.Log")["properties"]) == {"timestamp", "level", "message", "name", "file", "line"}


@pytest.mark.e2e  # a real WebSocket client timed against the server (subscriptions within 0.5 s): alone
def test_a_late_subscriber_gets_each_channel_latest_message():
    srv = FoxgloveServer(port=0)
    v = LiveView()
    try:
        srv.send(v.on_sample(*_est(4, 3.0, [1.0, 2.0, 3.0])))  # before any client: lost but for the latch

        async def go():
            async with FoxgloveClient(f"ws://127.0.0.1:{srv.port}") as c:
                await c.run(0.5)
                n = srv.resend_latched()
                await c.run(2.0, until=lambda g: g.of("larns/foxglove/station/4"))
                return c.got, n

        got, n = asyncio.run(go())
    finally:
        srv.stop()
    assert n >= 3  # tf, scene and the station's numbers
    assert [m["t_s"] for m in got.of("larns/foxglove/station/4")] == [3.0]
    assert srv.resend_latched() == 0  # nothing new subscribed


@pytest.mark.parametrize("argv, says", [
    (["view", "--port", "70000"], "larns view: --port 70000: expected 0..65535"),
    (["replay", "nonexistent.mcap", "--view", "0"], "larns replay --view: "),
    (["replay", "{bad}", "--view", "0"], "not an MCAP file"),
    (["replay", "{bad}", "--view", "99999"], "larns replay --view 99999: expected a port 0..65535"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, argv, says):
    import subprocess
    import sys

    bad = tmp_path / "bad.mcap"
    bad.write_text("garbage")
    argv = [a.replace("{bad}", str(bad)) for a in argv]
    r = subprocess.run([sys.executable, "-m", "larns", *argv], capture_output=True, text=True, timeout=60,
                       cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and says in lines[0] and "Traceback" not in r.stderr, r.stderr


def test_vehicle_estimate_and_truth_draw_tracks_and_numbers():
    v = LiveView()
    topics, ents = set(), set()
    for i in range(3):
        t = float(i)
        for m in ({"kind": "veh_estimate", "src": "veh1", "seq": i, "stamp_s": t, "t_s": t, "pos_m": [t, 0.0, 0.0],
                   "cov_m2": I3, "vel_m_s": [1.0, 0.0, 0.0], "algo": "cdekf-map", "n_updates": i},
                  {"kind": "veh_truth", "src": "veh1", "seq": i, "stamp_s": t, "t_s": t, "pos_m": [t, 0.1, 0.0],
                   "vel_m_s": [1.0, 0.0, 0.0]}):
            for o in v.on_sample(M.key_for(m), M.encode(m)):
                topics.add(o.topic)
                if o.topic == "larns/foxglove/scene":
                    ents |= {e["id"] for e in o.data["entities"]}
    assert "larns/foxglove/vehicle/veh1/cdekf-map" in topics
    assert {"vehicle/veh1/cdekf-map/track", "vehicle/veh1/truth/track", "vehicle/veh1/cdekf-map"} <= ents
