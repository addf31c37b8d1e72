"""Zenoh bus: peer mode (default) or client of a router; explicit endpoints, gossip scouting.

Topology. Zenoh >= 1.9 peers do not relay for each other, so every process needs a direct link to
every other one. Each process listens on its own endpoint and connects to a few **seed** endpoints;
gossip scouting (on) tells every peer about the others' locators and they link up directly (full
mesh). Multicast scouting is **off** by default (tests and containers never rely on it); shared
memory is off. ``--zenoh-config FILE`` (or the ``ZENOH_CONFIG`` environment variable) passes a
complete Zenoh JSON5 configuration through instead, for multi-host deployments; ``--listen`` /
``--connect`` given explicitly still override its endpoints.

Router topology (``--zenoh-mode client``). The full mesh costs N(N-1)/2 TCP links (keep-alives,
leases, per-link tasks in every process's runtime). Alternatively one **router** process
(``larns router --listen tcp/127.0.0.1:7447``; routing happens in Zenoh's Rust core) and every
other process a **client** connected to it (``--zenoh-mode client --connect tcp/127.0.0.1:7447``):
N links, one extra hop. A client does not listen and does no scouting. This is also the natural
multi-host layout (one router per host or site). Peer mode stays the default.

Open sessions only in freshly spawned processes: a Zenoh runtime inherited through ``fork()``
hangs. Use ``subprocess`` or ``multiprocessing.get_context("spawn")``.

The bus speaks bytes: ``publish(key, data)``, ``subscribe(keyexpr, callback(key, data))``.
Callbacks run on Zenoh's threads; hand the bytes over to your own thread (a queue) if the work is
not trivially thread-safe.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import random
import socket
import threading
import time
from typing import Callable, Iterable, Sequence

log = logging.getLogger("larns.bus")

DEFAULT_LISTEN = "tcp/127.0.0.1:0"
MODES = ("peer", "client", "router")


def add_bus_args(p: argparse.ArgumentParser) -> None:
    """The Zenoh options shared by every networked command."""
    g = p.add_argument_group("Zenoh")
    g.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                   help=f"endpoint to listen on (repeatable; default {DEFAULT_LISTEN})")
    g.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                   help="seed endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable); "
                        "gossip then links every peer to every other")
    g.add_argument("--zenoh-config", default=None, metavar="FILE",
                   help="full Zenoh JSON5 config (multi-host, TLS, routers); "
                        "default: $ZENOH_CONFIG if set")
    g.add_argument("--multicast", action="store_true",
                   help="enable multicast scouting (off by default)")
    g.add_argument("--zenoh-mode", choices=("peer", "client"), default="peer",
                   help="peer (default: full mesh via gossip) or client (connect only to the router(s) "
                        "given with --connect, e.g. one started with `larns router`)")
    g.add_argument("--secure", default=None, metavar="DIR", nargs="?", const="auto",
                   help="keystore made by `larns keys init`: TLS/mTLS links only, this process's own "
                        "certificate, access control and signed messages (docs/security.md)")


def bus_kwargs(args: argparse.Namespace) -> dict:
    return {"listen": args.listen or (), "connect": args.connect or (),
            "config_file": args.zenoh_config, "multicast": bool(getattr(args, "multicast", False)),
            "mode": getattr(args, "zenoh_mode", None) or "peer",
            **({"secure": secure_identity(args)} if getattr(args, "secure", None) else {})}


def secure_identity(args: argparse.Namespace) -> tuple[str, str]:
    """``(keystore DIR, common name)`` of a ``--secure`` process (``args.secure_cn`` set by the command)."""
    from net.security import KeystoreError

    cn = getattr(args, "secure_cn", None)
    if args.secure == "auto":
        raise KeystoreError("--secure needs a keystore DIR here (only `larns fleet --secure` makes a "
                            "temporary one); make one with `larns keys init DIR`")
    if not cn:
        raise KeystoreError("--secure: this command has no identity of its own in the keystore")
    return str(args.secure), cn


def bus_argv(listen: Iterable[str] = (), connect: Iterable[str] = (),
             config_file: str | None = None, mode: str = "peer", secure: str | None = None) -> list[str]:
    """Command-line flags reproducing a bus setup (for launchers). A client does not listen."""
    out: list[str] = ["--secure", str(secure)] if secure else []
    if mode != "peer":
        out += ["--zenoh-mode", mode]
        listen = () if mode == "client" else listen
    for e in listen:
        out += ["--listen", e]
    for e in connect:
        out += ["--connect", e]
    if config_file:
        out += ["--zenoh-config", config_file]
    return out


def _ephemeral_low(default: int = 32768) -> int:
    """The lowest port the kernel hands out to outgoing connections (Linux; else IANA's 49152 would
    do, ``default`` is Linux's)."""
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return default


def free_tcp_ports(n: int, host: str = "127.0.0.1") -> list[int]:
    """``n`` distinct currently free TCP ports (bound and released; a tiny race with other listeners
    accepted). They are drawn below the kernel's ephemeral range: a port the kernel picked for
    ``bind(0)`` is also a source port it gives to outgoing connections, and in a fleet the Zenoh
    sessions that start first dial out many of those before the later ones listen ("Address already
    in use" seen in CI). Falls back to ``bind(0)`` where the range is too small."""
    low = _ephemeral_low()
    pick = random.SystemRandom()
    socks: list[socket.socket] = []
    try:
        tries = 0
        while len(socks) < n:
            tries += 1
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            socks.append(s)
            port = pick.randrange(10000, low) if low > 11000 and tries <= 50 * n else 0
            try:
                s.bind((host, port))
            except OSError:
                socks.pop().close()
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


# Our Zenoh settings per mode (json5 values). Shared memory is off everywhere (containers, tests).
_NO_SHM = {"transport/shared_memory/enabled": "false"}
# Zenoh reassembles a message split over several batches (above ~64 KiB) up to this size before any
# of our code sees it (default 1 GiB: a stolen key could make every receiver hold that much); every
# LARNS payload is at most net.messages.MAX_PAYLOAD_BYTES (64 KiB, signature included) and every
# receiver refuses a larger one at decode. A message that fits in one batch is not checked by Zenoh.
MAX_ZENOH_MESSAGE_BYTES = 2 * 64 * 1024
# link again within ~0.1 s of a peer or router that restarts or reopens its session (a revocation:
# Bus.reopen); Zenoh's default (1 s, x2 up to 4 s) lost 1-3 s of traffic
_FAST_RETRY = {"connect/retry": '{"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2}'}
ROUTER_BLOCK_CLOSE_US = 500_000
# a message sent with congestion control DROP (every air message) waits this long (us) for room in a
# link's queue before it is dropped. Zenoh's 1 ms lost 1.4 % of a poll fleet's air messages on their
# way to the recorder alone (seed000-poll, 20 s: 37 of 2 633; every station had taken them): on a
# loaded 2-core host the link's sending task is not scheduled within 1 ms of a burst (a poll's nine
# replies, a nav, its estimate and truth). 50 ms (Zenoh's own wait for fragments): none lost. A reader
# that stops reading costs a publisher one such wait, not one per message: while the link stays
# congested Zenoh drops at once (tests/net/test_bus.py, docs/fleet.md "Recording loss")
WAIT_BEFORE_DROP_US = 50_000
_DROP_WAIT = {"transport/link/tx/queue/congestion_control/drop/wait_before_drop": str(WAIT_BEFORE_DROP_US)}
_MODE_SETTINGS: dict[str, dict[str, str]] = {
    # peers: full mesh through gossip (Zenoh >= 1.9 peers do not relay); keep retrying seeds that
    # are not up yet (processes start in any order)
    "peer": {"mode": '"peer"', **_NO_SHM, **_FAST_RETRY, **_DROP_WAIT,
             "scouting/gossip/enabled": "true",
             "scouting/gossip/multihop": "false",
             "scouting/gossip/autoconnect": '{"router": [], "peer": ["router", "peer"]}',
             "connect/timeout_ms": '{"router": -1, "peer": -1, "client": 0}',
             "connect/exit_on_failure": '{"router": false, "peer": false, "client": true}'},
    # clients of a router: wait for a router that is not up yet instead of failing
    "client": {"mode": '"client"', **_NO_SHM, **_FAST_RETRY, **_DROP_WAIT,
               "connect/timeout_ms": '{"router": -1, "peer": -1, "client": -1}',
               "connect/exit_on_failure": '{"router": false, "peer": false, "client": false}'},
    # router: no gossip; we never use storages or timestamps, so no HLC stamp per routed sample
    "router": {"mode": '"router"', **_NO_SHM, **_DROP_WAIT,
               "scouting/gossip/enabled": "false",
               "scouting/delay": "0",  # a router waited 0.5 s after binding its port, its clients with it
               "timestamping/enabled": '{"router": false, "peer": false, "client": false}',
               # a link blocked this long (us) on a full queue is closed: a message sent with BLOCK
               # (the journals) towards a link that died without a FIN (a cut backbone between two
               # routers) stalled the router's forwarding to every client for 5-10 s with Zenoh's
               # default 5 s, 1-2 s with 1 s, 0.5-1.1 s with 0.5 s (tests/larns/test_compose_sites.py,
               # docs/deploy.md "Two sites, a router each")
               "transport/link/tx/queue/congestion_control/block/wait_before_close": str(ROUTER_BLOCK_CLOSE_US),
               "connect/timeout_ms": '{"router": -1, "peer": -1, "client": 0}',
               "connect/exit_on_failure": '{"router": false, "peer": false, "client": true}'},
}


def _exchange_key(key: str) -> bool:
    """A ranging exchange's message (addressed request / response, poll, reply): whose timing decides
    whether the exchange closes in its slot, sent before navs and estimates (Zenoh priority REAL_TIME)."""
    return "/range/" in key or key.endswith("/poll") or "/reply/" in key


def make_config(listen: Sequence[str] = (), connect: Sequence[str] = (),
                config_file: str | None = None, multicast: bool = False, mode: str = "peer",
                secure: tuple[str, str] | None = None):
    """Build a ``zenoh.Config``: a pass-through file, or our defaults for ``mode`` (peer, client of
    a router, router), plus endpoints; ``secure=(keystore DIR, common name)`` adds that enclave's
    TLS/mTLS and access control (:func:`net.security.apply_security`)."""
    conf = _make_config(listen, connect, config_file, multicast, mode)
    if secure is not None:
        from net.security import apply_security

        apply_security(conf, *secure)
    return conf


def _make_config(listen, connect, config_file, multicast, mode):
    import zenoh

    if mode not in MODES:
        raise ValueError(f"zenoh mode must be one of {MODES}, not {mode!r}")

    config_file = config_file or os.environ.get("ZENOH_CONFIG") or None
    if config_file:
        conf = zenoh.Config.from_file(config_file)
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        return conf
    if mode == "client" and not connect:
        raise ValueError("client mode needs --connect <router endpoint>")
    settings = dict(_MODE_SETTINGS[mode])
    settings["transport/link/rx/max_message_size"] = str(MAX_ZENOH_MESSAGE_BYTES)
    settings["scouting/multicast/enabled"] = json.dumps(bool(multicast))
    settings["connect/endpoints"] = json.dumps(list(connect))
    if mode != "client":  # a client only dials its router(s)
        settings["listen/endpoints"] = json.dumps(list(listen) or [DEFAULT_LISTEN])
    conf = zenoh.Config()
    for key, value in settings.items():
        conf.insert_json5(key, value)
    return conf


# Zenoh's async runtimes (RON, read once per process when Zenoh starts): everything on one pool of
# TWO worker threads. A LARNS process moves a few hundred small messages per second; with Zenoh's
# default pools (rx: 2 workers, tx, app, acc, net: 1 each) every received sample wakes two or three
# threads, and on a 2-core machine running 50 station processes those wake-ups were most of the
# receive cost (docs/fleet.md, "Where the time goes"). One worker was tried first and is unsafe: when
# a peer dies without closing its TCP connections (a killed container, a cut cable), every process
# stopped receiving for ~9 s at once some 8-10 s later (seen in the compose test, when Zenoh's lease on
# the dead peer expired while its link was still stuck in a write; zenoh issues #1876, #2581). Two
# workers alone still left ~4 s pauses; two workers with the kernel giving up on the dead connection
# before the lease expires (`tcp_retries2 = 4`, docker-compose.yml, docs/deploy.md "Dead links") ran
# the timeline twice without any. Two workers cost the same CPU on a 10-station fleet (measured
# 2026-11-26). A ZENOH_RUNTIME set in the environment wins.
LEAN_RUNTIME = "(app: (worker_threads: 2), rx: (handover: app), tx: (handover: app), " \
               "acc: (handover: app), net: (handover: app))"


def use_lean_runtime() -> bool:
    """Select :data:`LEAN_RUNTIME` for this process unless ``ZENOH_RUNTIME`` is already set. Call it
    before the first Zenoh session of the process opens (later calls have no effect). Returns True
    if it set the variable (the caller removes it once the session is open, so that processes it
    spawns, a router for instance, keep Zenoh's defaults)."""
    if "ZENOH_RUNTIME" in os.environ:
        return False
    os.environ["ZENOH_RUNTIME"] = LEAN_RUNTIME
    return True


def _within(fn: Callable[[], None], timeout_s: float, name: str) -> bool:
    """Run ``fn`` on a daemon thread and wait up to ``timeout_s`` for it (a Zenoh session close has
    been seen to hang); its exceptions are swallowed. False if it had not finished by then."""
    done = threading.Event()

    def run() -> None:
        try:
            fn()
        except Exception:
            pass
        finally:
            done.set()

    threading.Thread(target=run, name=name, daemon=True).start()
    return done.wait(timeout_s)


class _Empty:
    @staticmethod
    def try_recv():
        return None


class _Ring:
    """A ring-buffer subscription that survives a reopen (:meth:`Bus.reopen` swaps ``sub``)."""

    CLOSED = _Empty()

    def __init__(self, sub):
        self.sub = sub

    def try_recv(self):
        sub = self.sub
        try:
            return sub.try_recv()
        except Exception:
            if sub is not self.sub:  # closed by a reopen meanwhile: the new one is read next time
                return None
            raise


class Bus:
    """One Zenoh session with cached publishers, byte-level subscribe and liveliness.

    ``lean_runtime`` (default on, except for routers): :func:`use_lean_runtime`."""

    def __init__(self, listen: Sequence[str] = (), connect: Sequence[str] = (),
                 config_file: str | None = None, multicast: bool = False, express: bool = True,
                 mode: str = "peer", lean_runtime: bool | None = None,
                 secure: tuple[str, str] | None = None):
        lean = mode != "router" if lean_runtime is None else lean_runtime
        set_env = lean and use_lean_runtime()
        import zenoh

        self._z = zenoh
        self.mode = mode
        # --secure: credentials first (a clear KeystoreError before any Zenoh start); publish signs
        self.security = None
        if secure is not None:
            from net.security import Security

            self.security = Security(*secure[:2])
        self._config_args = (list(listen), list(connect), config_file, multicast, mode)
        self._secure = secure
        try:
            self.session = zenoh.open(make_config(*self._config_args, secure))
        finally:
            if set_env:  # read once, when the first session starts Zenoh's runtimes
                os.environ.pop("ZENOH_RUNTIME", None)
        self._pubs: dict[str, object] = {}
        self._subs: list[object] = []
        self._tokens: list[object] = []
        self._decls: list[tuple] = []  # what this process declared, declared again by a reopen
        self._lock = threading.Lock()
        self._express = express
        self.closed = False
        self._reopening = False    # between closing the old session and declaring on the new one
        self.revoked: frozenset[str] = frozenset()  # names whose access rules the session left out
        self.reopened = 0
        self.dropped_in_reopen = 0
        self._watch: threading.Thread | None = None
        if self.security is not None:  # certificates and the revocation list on the bus (net/trust.py)
            self.security.attach(self)
            self._watch = threading.Thread(target=self._watch_revocations, name="larns-bus-revocations",
                                           daemon=True)
            self._watch.start()

    # ------------------------------------------------------------------ publish
    def publish(self, key: str, data: bytes, block: bool = False) -> None:
        """Publish ``data`` on ``key``. Default congestion control DROP (a late air message is a lost
        one anyway); ``block=True`` waits for room instead (journals, bulk senders, fuzzers)."""
        pub = self._pubs.get((key, block))
        if pub is None:
            with self._lock:  # (a reopen swaps the session under this lock)
                pub = self._pubs.get((key, block))
                if pub is None:
                    cc = self._z.CongestionControl
                    try:
                        pub = self.session.declare_publisher(
                            key, express=self._express and not block,
                            congestion_control=cc.BLOCK if block else cc.DROP,
                            priority=self._z.Priority.REAL_TIME if _exchange_key(key)
                            else self._z.Priority.DATA)
                    except Exception:
                        if self._reopening:  # the old session is closed, the new one not yet here
                            self.dropped_in_reopen += 1
                            return
                        raise
                    self._pubs[(key, block)] = pub
        if self.security is not None:
            data = self.security.seal(key, data)
        try:
            pub.put(data)
        except Exception:
            if self._reopening or pub not in self._pubs.values():  # a publisher of the closed session: lost
                self.dropped_in_reopen += 1
                return
            raise

    # ------------------------------------------------------------------ subscribe
    def subscribe(self, keyexpr: str, callback: Callable[[str, bytes], None]) -> object:
        """``callback(key, payload_bytes)`` for every sample on ``keyexpr`` (runs on a Zenoh thread).
        Exceptions in the callback are logged, never propagated into Zenoh."""

        def on_sample(sample) -> None:
            try:
                callback(str(sample.key_expr), sample.payload.to_bytes())
            except Exception:  # a subscriber bug must not kill the Zenoh thread
                log.exception("subscriber callback failed on %s", sample.key_expr)

        with self._lock:
            sub = self.session.declare_subscriber(keyexpr, on_sample)
            self._subs.append(sub)
            self._decls.append(("sub", keyexpr, on_sample))
        return sub

    def subscribe_ring(self, keyexpr: str, capacity: int = 8192) -> object:
        """Subscribe into a Zenoh ring buffer (Rust side, no Python wake-up per sample; the oldest
        samples are dropped when full). Read with :meth:`drain` at times of your choosing: for
        many small, not latency-critical messages this costs far less CPU than a callback."""
        with self._lock:
            ring = _Ring(self.session.declare_subscriber(keyexpr, self._z.handlers.RingChannel(int(capacity))))
            self._subs.append(ring.sub)
            self._decls.append(("ring", keyexpr, int(capacity), ring))
        return ring

    @staticmethod
    def drain(sub, max_n: int = 100_000) -> list[tuple[str, bytes]]:
        """Everything waiting in a :meth:`subscribe_ring` subscription, oldest first."""
        out: list[tuple[str, bytes]] = []
        for _ in range(max_n):
            sample = sub.try_recv()
            if sample is None:
                break
            out.append((str(sample.key_expr), sample.payload.to_bytes()))
        return out

    # ------------------------------------------------------------------ liveliness
    def declare_token(self, key: str) -> object:
        with self._lock:
            tok = self.session.liveliness().declare_token(key)
            self._tokens.append(tok)
            self._decls.append(("token", key))
        return tok

    def subscribe_liveliness(self, keyexpr: str, callback: Callable[[str, bool], None],
                             history: bool = True) -> object:
        """``callback(key, alive)``: True when a token appears, False when it goes away."""
        put = self._z.SampleKind.PUT

        def on_sample(sample) -> None:
            try:
                callback(str(sample.key_expr), sample.kind == put)
            except Exception:
                log.exception("liveliness callback failed")

        with self._lock:
            sub = self.session.liveliness().declare_subscriber(keyexpr, on_sample, history=history)
            self._subs.append(sub)
            self._decls.append(("live", keyexpr, on_sample, history))
        return sub

    def alive(self, keyexpr: str, timeout_s: float = 1.0) -> list[str]:
        """Keys of liveliness tokens currently present under ``keyexpr``."""
        out = []
        for reply in self.session.liveliness().get(keyexpr, timeout=timeout_s):
            ok = getattr(reply, "ok", None)
            if ok is not None:
                out.append(str(ok.key_expr))
        return out

    def peers(self) -> list[str]:
        """Zenoh ids of the peers this session has a direct link to."""
        return [str(z) for z in self.session.info.peers_zid()]

    def routers(self) -> list[str]:
        """Zenoh ids of the routers this session is linked to (client mode)."""
        return [str(z) for z in self.session.info.routers_zid()]

    # ------------------------------------------------------------------ lifecycle
    def reopen(self, revoked: frozenset[str], timeout_s: float = 5.0) -> None:
        """Close the Zenoh session and open a new one on the same endpoints whose access rules leave
        out the common names ``revoked`` (``net.security.without_subjects``): Zenoh reads
        ``access_control`` only when a session opens (1.10: a change on an open session has no
        effect, the admin space refuses it). Everything this process declared (subscriptions, ring
        buffers, liveliness tokens and subscriptions, the trust queryables) is declared again on the
        new session; publishers on first use; a sample published meanwhile is lost
        (:attr:`dropped_in_reopen`). Its peers, clients or router link again by themselves (their
        ``connect/retry``)."""
        root, cn, guard = (*self._secure, None)[:3]
        old = self.session
        self._reopening = True
        for d in self._decls:
            if d[0] == "ring":
                d[3].sub = _Ring.CLOSED  # (read as empty until the new session's ring is in)
        if not _within(old.close, timeout_s, "larns-bus-reopen"):
            log.warning("bus: the old Zenoh session did not close within %.0f s; opening the new one anyway", timeout_s)
        try:
            new = self._z.open(make_config(*self._config_args, (root, cn, guard, revoked)))
        except Exception:
            self._reopening = False
            raise
        with self._lock:
            self.session = new
            self._pubs.clear()
            self._subs, self._tokens = [], []
            for d in self._decls:
                if d[0] == "sub":
                    self._subs.append(new.declare_subscriber(d[1], d[2]))
                elif d[0] == "ring":
                    d[3].sub = new.declare_subscriber(d[1], self._z.handlers.RingChannel(d[2]))
                    self._subs.append(d[3].sub)
                elif d[0] == "token":
                    self._tokens.append(new.liveliness().declare_token(d[1]))
                else:
                    self._subs.append(new.liveliness().declare_subscriber(d[1], d[2], history=d[3]))
            self.revoked, self.reopened = frozenset(revoked), self.reopened + 1
            self._reopening = False
        if self.security is not None:
            self.security.attach(self)

    #: how often a secure session compares the newest revocation list with its access rules
    REVOCATION_CHECK_S = 0.2

    def _watch_revocations(self) -> None:
        """Reopen the session when the newest revocation list (the keystore's ``crl.pem`` re-read
        every 2 s, or one put on or served by the bus: net/trust.py) revokes every certificate of a
        name the access rules admit - or when a re-issued certificate makes it usable again. A
        process that verifies no signature (a router, a monitor) reads the certificates from its
        keystore's files; one with a receive guard knows the certificates of those who spoke to it
        (the guard loads them on its own thread: the watch then only reads)."""
        from net.security import access_control

        sec = self.security
        names = sorted({c for sub in access_control(sec.ks, sec.cn)["subjects"]
                        for c in sub["cert_common_names"]} - {sec.cn})
        while not self.closed:
            time.sleep(self.REVOCATION_CHECK_S)
            try:
                now = sec.verifier.revoked_among(names, load=not sec.verifies)
                if now != self.revoked and not self.closed:
                    t0 = time.monotonic()
                    self.reopen(now)
                    log.warning("bus %s: access rules reopened in %.2f s; refused as revoked: %s", sec.cn,
                                time.monotonic() - t0, ", ".join(sorted(now)) or "none")
            except RuntimeError:  # the receive guard added a certificate meanwhile: next tick
                continue
            except Exception:  # noqa: BLE001 - the watch must not die (the next tick retries)
                log.warning("bus %s: revocation watch failed", sec.cn, exc_info=True)

    def close(self, timeout_s: float = 5.0) -> bool:
        """Withdraw the tokens and close the session, within ``timeout_s``: a Zenoh session close has
        been seen to hang (a station not gone 20 s after SIGTERM, twice in full suites). Returns False
        if it did not finish in time (it goes on in a daemon thread; the process may exit)."""
        if self.closed:
            return True
        self.closed = True
        # The revocation watch ends within a tick once closed; waited for, so that no thread of ours is
        # inside a native call (the keystore's certificates, a reopen) while the interpreter finalizes:
        # a thread stopped there aborts the process ("FATAL: exception not rethrown").
        if self._watch is not None and self._watch is not threading.current_thread():
            self._watch.join(timeout_s)

        def _close() -> None:
            if self.security is not None:
                self.security.close()  # the replay history, for a restart
            for t in self._tokens:
                try:
                    t.undeclare()
                except Exception:
                    pass
            self.session.close()

        if _within(_close, timeout_s, "larns-bus-close"):
            return True
        log.warning("bus: the Zenoh session did not close within %.0f s; leaving it to the process exit", timeout_s)
        return False

    def __enter__(self) -> "Bus":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
