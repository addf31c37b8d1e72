#!/usr/bin/env bash
# The issue-15 bar on this machine (docs/security.md): a secure 10-station fleet through a router,
# DURATION fleet seconds, once without and once with `larns attack all` running alongside; then the
# mean horizontal error of each recording (`larns report`) and the attack drop counters.
#
#   scripts/secure-bar.sh [DURATION=120] [OUT=runs/secure-bar]
#
# Loopback only; every process stops by itself. Prints where the recordings and logs are.
set -euo pipefail
cd "$(dirname "$0")/.."
DUR=${1:-120}
OUT=${2:-runs/secure-bar}
L=${LARNS:-.venv/bin/larns}
mkdir -p "$OUT"
KEYS="$OUT/keys"
rm -rf "$KEYS"
"$L" keys init "$KEYS" --stations 1-10 --aircraft ac1
PORT=$(.venv/bin/python -c 'from net.bus import free_tcp_ports; print(free_tcp_ports(1)[0])')
EP="tls/127.0.0.1:$PORT"
for run in clean attacked; do
  "$L" router --secure "$KEYS" --listen "$EP" -q --duration $((DUR + 90)) &
  RPID=$!
  sleep 2
  if [ "$run" = attacked ]; then
    ( sleep 25; "$L" attack all --secure "$KEYS" --zenoh-mode client --connect "$EP" \
        --duration $((DUR - 30)) --as 3 --victim 5 --rate 20000 > "$OUT/attack.jsonl" 2> "$OUT/attack.err" ) &
    APID=$!
  fi
  "$L" fleet --secure "$KEYS" --topology router --connect "$EP" --duration "$DUR" --no-table \
      --record "$OUT/$run.mcap" --json "$OUT/$run.json" > "$OUT/$run.table" 2> "$OUT/$run.err" || true
  [ "$run" = attacked ] && wait "$APID" || true
  kill -INT "$RPID" 2>/dev/null || true; wait "$RPID" 2>/dev/null || true
  "$L" report "$OUT/$run.mcap" -o "$OUT/$run.report" > "$OUT/$run.report.txt" 2>&1 || true
  echo "== $run: $(grep -h -m2 "horizontal" "$OUT/$run.report/report.md" | tr "\n" " " || echo "no report")"
  grep -h "stopped:" "$OUT/$run.mcap.logs"/station_*.log | sed 's/^/   /' || true
done
echo "== attacks sent:"; cat "$OUT/attack.jsonl" 2>/dev/null || true
echo "== drop counters (station estimate 'dropped' field; by reason in the station logs' warnings):"
grep -h "dropped" "$OUT/attacked.mcap.logs"/station_*.log | tail -n 20 || true
