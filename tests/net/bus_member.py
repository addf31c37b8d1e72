"""The bus test process shared by tests/net/test_bus.py (peers) and tests/net/test_bus_router.py (clients).

``python -c SCRIPT NAME N MODE LISTEN ENDPOINT...``: a Bus in ``MODE`` (peer or client), listening on
``LISTEN`` ("-": nowhere, as a client) and connecting to the endpoints; it publishes its name until
it has heard N names (or 15 s), keeps publishing a second for slower members, and prints one JSON
line: names heard, liveliness tokens seen, peer and router counts.
"""

import textwrap

SCRIPT = textwrap.dedent("""
    import json, sys, time
    from net.bus import Bus
    name, n, mode, listen, endpoints = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4], sys.argv[5:]
    b = Bus(listen=[] if listen == "-" else [listen], connect=endpoints, mode=mode)
    got = set()
    b.subscribe("test/data/*", lambda k, d: got.add(d.decode()))
    b.declare_token("test/alive/" + name)
    t0 = time.time()
    while time.time() - t0 < 15 and len(got) < n:
        b.publish("test/data/" + name, name.encode())
        time.sleep(0.1)
    alive = sorted(b.alive("test/alive/*"))
    for _ in range(10):  # keep publishing so slower members finish too
        b.publish("test/data/" + name, name.encode()); time.sleep(0.1)
    print(json.dumps({"name": name, "got": sorted(got), "alive": alive, "peers": len(b.peers()),
                      "routers": len(b.routers())}))
    b.close()
""")
