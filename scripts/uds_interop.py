#!/usr/bin/env python3
"""Interop check: python-can (interface='socketcand') + can-isotp + udsoncan against
roomcal's UDS server (examples/uds_fake_server.rs, fake backend) on a socketcand
endpoint on 127.0.0.1. Not part of `cargo test`.

    python3 -m venv /tmp/udsvenv && /tmp/udsvenv/bin/pip install -r scripts/requirements-uds.txt
    /tmp/udsvenv/bin/python scripts/uds_interop.py            # builds and starts the server
    /tmp/udsvenv/bin/python scripts/uds_interop.py --port 29536   # a server already running

Prints one line per check and ends with 'N passed, N failed'; exit status 1 on failure.
"""
import argparse
import hashlib
import hmac
import os
import struct
import subprocess
import sys
import time

import can
import isotp
import udsoncan
from udsoncan.client import Client
from udsoncan.connections import PythonIsoTpConnection
from udsoncan.exceptions import NegativeResponseException

SECRET = b"interop-secret"
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class Raw(udsoncan.DidCodec):
    """Hands the record bytes through; decoded below with struct."""

    def __init__(self, length=None):
        self.length = length

    def encode(self, *args):
        raise NotImplementedError

    def decode(self, payload):
        return bytes(payload)

    def __len__(self):
        if self.length is None:
            raise udsoncan.DidCodec.ReadAllRemainingData
        return self.length


def key_for(seed, secret=SECRET):
    return hmac.new(secret, bytes(seed), hashlib.sha256).digest()[:16]


RESULTS = []


def check(name, cond, detail=""):
    RESULTS.append(bool(cond))
    print(f"{'PASS' if cond else 'FAIL'} {name}{(': ' + detail) if detail else ''}")


def expect_nrc(name, fn, code):
    try:
        fn()
    except NegativeResponseException as e:
        check(name, e.response.code == code, f"NRC 0x{e.response.code:02X}")
        return
    check(name, False, "no negative response")


def start_server():
    cmd = ["cargo", "run", "-q", "--example", "uds_fake_server", "--",
           "--listen", "127.0.0.1:0", "--secret", SECRET.decode(), "--run-polls", "100"]
    proc = subprocess.Popen(cmd, cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    if not line.startswith("listening on "):
        proc.kill()
        sys.exit(f"server did not start: {line!r}")
    port = int(line.strip().rsplit(":", 1)[1])
    return proc, port


def make_client(bus, blocksize, stmin):
    addr = isotp.Address(isotp.AddressingMode.Normal_11bits, txid=0x7A0, rxid=0x7A8)
    params = {"blocksize": blocksize, "stmin": stmin, "tx_padding": None,
              "rx_flowcontrol_timeout": 1000, "rx_consecutive_frame_timeout": 1000}
    stack = isotp.CanStack(bus=bus, address=addr, params=params)
    conn = PythonIsoTpConnection(stack)
    cfg = dict(udsoncan.configs.default_client_config)
    cfg.update({
        "data_identifiers": {0xC001: Raw(9), 0xC002: Raw(), 0xC003: Raw(28), 0xC004: Raw(9)},
        "security_algo": lambda level, seed, params: key_for(seed, params),
        "security_algo_params": SECRET,
        "request_timeout": 10, "p2_timeout": 1, "p2_star_timeout": 6,
        "use_server_timing": False,
    })
    return conn, Client(conn, config=cfg)


def run(port):
    bus = can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="can0")
    conn, client = make_client(bus, blocksize=2, stmin=5)
    with client:
        r = client.change_session(3)
        t = r.service_data
        check("0x10 extended: P2 50 ms, P2* 5000 ms",
              abs(t.p2_server_max - 0.05) < 1e-9 and abs(t.p2_star_server_max - 5.0) < 1e-9,
              f"{t.p2_server_max} s, {t.p2_star_server_max} s")

        state = client.read_data_by_identifier(0xC001).service_data.values[0xC001]
        st, gen, ts = struct.unpack(">BII", state)
        check("0xC001 state", (st, gen, ts) == (0, 7, 1_700_000_000), f"{st} {gen} {ts}")

        t0 = time.perf_counter()
        intr = client.read_data_by_identifier(0xC002).service_data.values[0xC002]
        dt = time.perf_counter() - t0
        model, fx, fy, cx, cy, n = struct.unpack(">B4fB", intr[:18])
        dist = struct.unpack(f">{n}f", intr[18:])
        # 5 consecutive frames, 4 gaps of at least STmin.
        check("0xC002 intrinsics (multi-frame, BS 2, STmin 5 ms)",
              (model, fx, fy, cx, cy, n) == (0, 1000.0, 1000.5, 960.0, 600.0, 5)
              and abs(dist[0] + 0.25) < 1e-7 and dt >= 0.019,
              f"fx {fx} fy {fy} cx {cx} cy {cy} k {dist}, {dt * 1e3:.1f} ms")

        ext = struct.unpack(">7f", client.read_data_by_identifier(0xC003).service_data.values[0xC003])
        check("0xC003 extrinsic", [round(v, 4) for v in ext] == [0.5, -0.5, 0.5, -0.5, 0.05, 0.42, -0.28],
              str([round(v, 4) for v in ext]))
        q = struct.unpack(">2fB", client.read_data_by_identifier(0xC004).service_data.values[0xC004])
        check("0xC004 quality", q == (0.125, 0.75, 6), str(q))

        # Raw requests for the cases udsoncan would refuse to send.
        conn.send(bytes([0x22, 0xF1, 0x90]))
        check("unknown DID -> 0x31", conn.wait_frame(timeout=2) == bytes([0x7F, 0x22, 0x31]))
        conn.send(bytes([0x22]) + bytes([0xC0, 0x01]) * 8)  # 17 bytes: multi-frame request
        r = conn.wait_frame(timeout=2)
        check("8 DIDs in one multi-frame request", r is not None and len(r) == 1 + 8 * 11, f"{len(r or b'')} bytes")
        conn.send(bytes([0x11, 0x01]))
        check("ECUReset -> 0x11", conn.wait_frame(timeout=2) == bytes([0x7F, 0x11, 0x11]))

        expect_nrc("routine while locked -> 0x33", lambda: client.start_routine(0xC101), 0x33)
        client.config["security_algo_params"] = b"wrong"
        expect_nrc("wrong key -> 0x35", lambda: client.unlock_security_access(1), 0x35)
        client.config["security_algo_params"] = SECRET
        client.unlock_security_access(1)
        check("security unlocked", True)

        t0 = time.perf_counter()
        r = client.start_routine(0xC100)
        dt = time.perf_counter() - t0
        rec = r.service_data.routine_status_record
        check("0xC100 start: 0x78 then final", rec == bytes([4, 0, 0, 0, 8]) and dt >= 0.9,
              f"{rec.hex()} after {dt:.2f} s")
        r = client.get_routine_result(0xC100)
        check("0xC100 results", r.service_data.routine_status_record == bytes([4, 0, 0, 0, 8]))
        r = client.start_routine(0xC101)
        check("0xC101 rollback", r.service_data.routine_status_record == bytes([0, 0, 0, 7]))
        client.tester_present()
        check("tester present", True)

        n = 200
        t0 = time.perf_counter()
        for _ in range(n):
            client.read_data_by_identifier(0xC001)
        dt = time.perf_counter() - t0
        print(f"INFO {n} ReadDataByIdentifier round trips: {dt / n * 1e3:.2f} ms each")

        # A session change relocks; three wrong keys lock SecurityAccess for 10 s.
        client.change_session(3)
        client.config["security_algo_params"] = b"wrong"
        expect_nrc("wrong key 1 -> 0x35", lambda: client.unlock_security_access(1), 0x35)
        expect_nrc("wrong key 2 -> 0x35", lambda: client.unlock_security_access(1), 0x35)
        expect_nrc("wrong key 3 -> 0x36", lambda: client.unlock_security_access(1), 0x36)
        expect_nrc("seed while locked -> 0x37", lambda: client.request_seed(1), 0x37)
    bus.shutdown()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--port", type=int, help="use a server already listening on 127.0.0.1:PORT")
    args = ap.parse_args()
    proc = None
    port = args.port
    if port is None:
        proc, port = start_server()
    try:
        run(port)
    finally:
        if proc is not None:
            proc.stdin.close()
            proc.wait(timeout=10)
    passed = sum(RESULTS)
    print(f"{passed} passed, {len(RESULTS) - passed} failed")
    return 0 if passed == len(RESULTS) else 1


if __name__ == "__main__":
    sys.exit(main())
