#!/usr/bin/env python3
"""Interop check of the roomcal replay daemon's UDS service (ISO 14229 on ISO 15765-2) over
its socketcand endpoint, with python-can (interface 'socketcand'), can-isotp and udsoncan as
the service tool, plus raw CAN frames for the robustness checks. Not part of `cargo test`.

scripts/uds_interop.sh runs everything (venv, release build, daemon, checks). By hand:

    python scripts/uds_interop.py --seed-store DIR     # generation 1 = the fixture's truth
    roomcal daemon --config CFG                        # config/replay-uds.toml, store DIR
    python scripts/uds_interop.py --port PORT --store DIR --secret-file SECRET

Checks, in order: every DID against STORE/current.json; session and security rules
(routines refused in the default session, without SecurityAccess, with a wrong key; three
wrong keys lock SecurityAccess for 10 s); robustness while the lock runs (malformed ISO-TP
frames, unexpected consecutive and flow-control frames, wrong UDS lengths, flow control
honoured, a flood of 10,000 requests with the request rate measured); unlock with the HMAC
key; RoutineControl 0xC100 start (0x78 responsePending until the run ends) and a new
generation in the store; 0xC101 rollback (a new generation restoring the one before); S3.

Prints one line per check (PASS/FAIL), RATE lines for the measured request rates, and
'N passed, M failed'; exit status 1 on any failure.
"""
import argparse
import hashlib
import hmac
import json
import logging
import math
import os
import socket
import struct
import sys
import time
import zlib

import can
import isotp
import udsoncan
from udsoncan.client import Client
from udsoncan.connections import PythonIsoTpConnection
from udsoncan.exceptions import NegativeResponseException

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TRUTH = os.path.join(REPO, "fixtures", "six-boards-pandar64", "truth.json")
REQ, RESP = 0x7A0, 0x7A8
DIDS = (0xC001, 0xC002, 0xC003, 0xC004)
LOCKOUT_S = 10.0
S3_S = 5.0

RESULTS = []


def check(name, cond, detail=""):
    RESULTS.append(bool(cond))
    print(f"{'PASS' if cond else 'FAIL'} {name}{(': ' + detail) if detail else ''}", flush=True)
    return bool(cond)


def hexs(b):
    return "none" if b is None else bytes(b).hex(" ")


def f32(v):
    """v rounded to IEEE single precision, as the daemon encodes it."""
    return struct.unpack(">f", struct.pack(">f", v))[0]


# ---------------------------------------------------------------- the store

CRC_MARK = ',\n  "crc32": "'


def write_record(path, record):
    """A store record file: pretty JSON with a trailing crc32 member over the text before
    it (src/store.rs: canonical form = the bytes before the member + closing brace)."""
    canonical = json.dumps(record, indent=2)
    body = canonical[: -len("\n}")]
    crc = zlib.crc32(canonical.encode()) & 0xFFFFFFFF
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        f.write(f'{body}{CRC_MARK}{crc:08x}"\n}}\n')
    os.replace(tmp, path)


def read_record(path):
    """(record, crc_ok) of a store record file."""
    with open(path) as f:
        text = f.read()
    at = text.rfind(CRC_MARK)
    want = text[at + len(CRC_MARK):at + len(CRC_MARK) + 8] if at >= 0 else ""
    got = zlib.crc32((text[:at] + "\n}").encode()) & 0xFFFFFFFF if at >= 0 else None
    return json.loads(text), want == f"{got:08x}"


def seed_store(store):
    """Generation 1 = the fixture's ground truth (close to what the solver finds, so the
    quality gate's change limits pass, but not equal to it: a rollback is visible)."""
    with open(TRUTH) as f:
        truth = json.load(f)
    record = {
        "status": "accepted",
        "camera": truth["camera"],
        "lidar_to_camera": truth["lidar_to_camera"],
        "uncertainty": {"fx": 0.5, "fy": 0.5, "cx": 0.5, "cy": 0.5,
                        "rotation_deg": 0.05, "translation_m": 0.005},
        "quality": {"corner_rms_px": 0.2, "hole_rms_px": 1.5, "boards": 6},
        "boards": [],
        "generation": 1,
        "time": int(time.time()) - 86400,
    }
    os.makedirs(os.path.join(store, "history"), exist_ok=True)
    write_record(os.path.join(store, "history", "gen-000001.json"), record)
    write_record(os.path.join(store, "current.json"), record)


def current(store):
    return read_record(os.path.join(store, "current.json"))


def history(store, generation):
    return read_record(os.path.join(store, "history", f"gen-{generation:06d}.json"))[0]


# ---------------------------------------------------------------- DID decoding

def quat_to_matrix(w, x, y, z):
    return [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]


def decode_did(did, b):
    b = bytes(b)
    if did == 0xC001:
        return struct.unpack(">BII", b) if len(b) == 9 else None
    if did == 0xC002:
        if len(b) < 18:
            return None
        model, fx, fy, cx, cy, n = struct.unpack(">B4fB", b[:18])
        if len(b) != 18 + 4 * n:
            return None
        return model, fx, fy, cx, cy, list(struct.unpack(f">{n}f", b[18:]))
    if did == 0xC003:
        return struct.unpack(">7f", b) if len(b) == 28 else None
    if did == 0xC004:
        return struct.unpack(">2fB", b) if len(b) == 9 else None
    return None


def split_rdbi(payload):
    """{did: record bytes} of a positive 0x22 response (62 DID rec DID rec ...)."""
    lens = {0xC001: 9, 0xC003: 28, 0xC004: 9}
    out, i = {}, 1
    while i + 2 <= len(payload):
        did = int.from_bytes(payload[i:i + 2], "big")
        i += 2
        n = lens.get(did)
        if n is None:  # 0xC002: 18 + 4 n
            n = 18 + 4 * payload[i + 17] if i + 18 <= len(payload) else len(payload) - i
        out[did] = bytes(payload[i:i + n])
        i += n
    return out


def check_dids(tag, records, store, states):
    """Every DID against current.json; `states`: the state bytes acceptable now."""
    rec, crc_ok = current(store)
    check(f"{tag}: current.json checksum valid", crc_ok)
    st = decode_did(0xC001, records.get(0xC001, b""))
    check(f"{tag}: 0xC001 state/generation/time = current.json",
          st is not None and st[0] in states and st[1] == rec["generation"] and st[2] == rec["time"],
          f"DID {st}, store generation {rec['generation']} time {rec['time']}")
    cam = rec["camera"]
    k = decode_did(0xC002, records.get(0xC002, b""))
    want_model = {"pinhole-radtan": 0, "fisheye": 1}[cam["model"]]
    ok = (k is not None and k[0] == want_model
          and list(k[1:5]) == [f32(cam[c]) for c in ("fx", "fy", "cx", "cy")]
          and k[5] == [f32(d) for d in cam["distortion"]])
    check(f"{tag}: 0xC002 intrinsics = current.json (f32)", ok,
          f"fx {k[1]:.4f} fy {k[2]:.4f} cx {k[3]:.4f} cy {k[4]:.4f} k {[round(d, 6) for d in k[5]]}"
          if k else hexs(records.get(0xC002)))
    e = decode_did(0xC003, records.get(0xC003, b""))
    ext = rec.get("lidar_to_camera")
    if e is None or ext is None:
        check(f"{tag}: 0xC003 extrinsic = current.json", False, hexs(records.get(0xC003)))
    else:
        w, x, y, z, tx, ty, tz = e
        r = quat_to_matrix(w, x, y, z)
        err = max(abs(r[i][j] - ext["rotation"][i][j]) for i in range(3) for j in range(3))
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        ok = err < 2e-6 and abs(norm - 1) < 1e-6 and [tx, ty, tz] == [f32(t) for t in ext["translation"]]
        check(f"{tag}: 0xC003 extrinsic = current.json", ok,
              f"|R(q) - R| {err:.1e}, |q| {norm:.7f}, t [{tx:.5f} {ty:.5f} {tz:.5f}]")
    q = decode_did(0xC004, records.get(0xC004, b""))
    qual = rec["quality"]
    check(f"{tag}: 0xC004 quality = current.json",
          q is not None and q == (f32(qual["corner_rms_px"]), f32(qual["hole_rms_px"]), qual["boards"]),
          str(q))
    return rec


def decode_sensor_table(b):
    """DID 0xC010: u8 n, n x (u8 kind, u8 name length, name) -> [(kind, name)], or None."""
    b, out, i = bytes(b), [], 1
    if not b:
        return None
    for _ in range(b[0]):
        if i + 2 > len(b) or i + 2 + b[i + 1] > len(b):
            return None
        out.append((b[i], b[i + 2:i + 2 + b[i + 1]].decode("ascii", "replace")))
        i += 2 + b[i + 1]
    return out if i == len(b) else None


def check_sensor_dids(tag, uds, records):
    """The one-pair rig's per-sensor DIDs (0xC010, 0xC200 + i, 0xC300 + i) against the fixed ones."""
    read = lambda d: uds.client.read_data_by_identifier(d).service_data.values[d]  # noqa: E731
    table = decode_sensor_table(read(0xC010))
    check(f"{tag}: 0xC010 sensor table = camera 0 'camera', LiDAR 1 'lidar'",
          table == [(0, "camera"), (1, "lidar")], str(table))
    check(f"{tag}: 0xC200 (camera 0) = 0xC002", read(0xC200) == records.get(0xC002), hexs(read(0xC200)))
    check(f"{tag}: 0xC301 (LiDAR 1 -> camera 0) = 0xC003", read(0xC301) == records.get(0xC003),
          hexs(read(0xC301)))
    identity = struct.pack(">7f", 1, 0, 0, 0, 0, 0, 0)
    check(f"{tag}: 0xC300 (camera 0 to itself) = identity", read(0xC300) == identity, hexs(read(0xC300)))
    uds.expect_nrc(f"{tag}: 0xC201 (a LiDAR has no intrinsics) -> 0x31", lambda: read(0xC201), 0x31)
    uds.expect_nrc(f"{tag}: 0xC302 (no sensor 2) -> 0x31", lambda: read(0xC302), 0x31)


# ---------------------------------------------------------------- udsoncan side

class Raw(udsoncan.DidCodec):
    """Hands the record bytes through; decoded with struct."""

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


def key_for(seed, secret):
    return hmac.new(secret, bytes(seed), hashlib.sha256).digest()[:16]


def open_bus(port):
    # tcp_tune: TCP_NODELAY, else Nagle and delayed ACKs add tens of ms per frame.
    return can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="can0",
                   tcp_tune=True)


class Uds:
    """udsoncan over can-isotp over python-can's socketcand interface."""

    def __init__(self, port, secret):
        self.bus = open_bus(port)
        addr = isotp.Address(isotp.AddressingMode.Normal_11bits, txid=REQ, rxid=RESP)
        params = {"blocksize": 2, "stmin": 5, "tx_padding": None,
                  "rx_flowcontrol_timeout": 1000, "rx_consecutive_frame_timeout": 1000}
        self.conn = PythonIsoTpConnection(isotp.CanStack(bus=self.bus, address=addr, params=params))
        cfg = dict(udsoncan.configs.default_client_config)
        cfg.update({
            "data_identifiers": {0xC001: Raw(9), 0xC002: Raw(), 0xC003: Raw(28), 0xC004: Raw(9),
                                 0xC010: Raw(), 0xC200: Raw(), 0xC201: Raw(),
                                 0xC300: Raw(28), 0xC301: Raw(28), 0xC302: Raw(28)},
            "security_algo": lambda level, seed, params: key_for(seed, params),
            "security_algo_params": secret,
            "request_timeout": 10, "p2_timeout": 1, "p2_star_timeout": 6,
            "use_server_timing": False,
        })
        self.client = Client(self.conn, config=cfg)
        self.client.open()

    def close(self):
        self.client.close()
        self.bus.shutdown()

    def read_all(self):
        return {d: self.client.read_data_by_identifier(d).service_data.values[d] for d in DIDS}

    def expect_nrc(self, name, fn, code):
        try:
            fn()
        except NegativeResponseException as e:
            return check(name, e.response.code == code, f"NRC 0x{e.response.code:02X}")
        except Exception as e:  # noqa: BLE001 (a timeout or decoding error is a failure)
            return check(name, False, f"{type(e).__name__}: {e}")
        return check(name, False, "positive response")

    def raw(self, request, timeout=2.0):
        self.conn.send(bytes(request))
        return self.conn.wait_frame(timeout=timeout)


# ---------------------------------------------------------------- raw CAN side

class RawTp:
    """Raw frames on 0x7A0 / 0x7A8 with python-can, and a minimal ISO-TP client for the
    cases can-isotp would refuse to produce."""

    def __init__(self, port):
        self.port = port
        self.bus = open_bus(port)

    def close(self):
        self.bus.shutdown()

    def send(self, data, extended=False, arb=REQ):
        self.bus.send(can.Message(arbitration_id=arb, data=bytes(data), is_extended_id=extended))

    def recv(self, timeout):
        """The next response frame (ID 0x7A8, 11-bit) within `timeout` s, else None."""
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                return None
            m = self.bus.recv(left)
            if m is not None and m.arbitration_id == RESP and not m.is_extended_id:
                return bytes(m.data)

    def quiet(self, t=0.3):
        """True if no response frame arrives within t s."""
        return self.recv(t) is None

    def drain(self, t=0.05):
        while self.recv(t) is not None:
            pass

    def response(self, first, timeout=2.0, fc=(0, 0)):
        """Reassembles one message whose first frame is `first` (FC: block size, STmin)."""
        if first is None:
            return None
        t = first[0] >> 4
        if t == 0:
            return first[1:1 + (first[0] & 0x0F)]
        if t != 1:
            return None
        total = ((first[0] & 0x0F) << 8) | first[1]
        data = bytearray(first[2:8])
        self.send([0x30, fc[0], fc[1]])
        sn, in_block = 1, 0
        while len(data) < total:
            cf = self.recv(timeout)
            if cf is None or cf[0] != 0x20 | sn:
                return None
            data += cf[1:1 + min(7, total - len(data))]
            sn, in_block = (sn + 1) & 0x0F, in_block + 1
            if fc[0] and in_block == fc[0] and len(data) < total:
                self.send([0x30, fc[0], fc[1]])
                in_block = 0
        return bytes(data)

    def request(self, payload, timeout=2.0):
        """Sends a request (single or segmented) and returns the whole response message,
        skipping 0x78 responsePending."""
        payload = bytes(payload)
        if len(payload) <= 7:
            self.send(bytes([len(payload)]) + payload)
        else:
            self.send(bytes([0x10 | (len(payload) >> 8), len(payload) & 0xFF]) + payload[:6])
            fc = self.recv(timeout)
            if fc is None or fc[0] >> 4 != 3:
                return None
            sn, rest = 1, payload[6:]
            while rest:
                self.send(bytes([0x20 | sn]) + rest[:7])
                rest, sn = rest[7:], (sn + 1) & 0x0F
        while True:
            r = self.response(self.recv(timeout), timeout)
            if r is None or r[:1] != b"\x7F" or len(r) < 3 or r[2] != 0x78:
                return r


# ---------------------------------------------------------------- the checks

def robustness(raw, flood):
    """Malformed and unexpected frames, wrong lengths, flow control, the flood."""
    # ISO 15765-2 (9.6): invalid PCI, wrong lengths and unexpected frames are ignored.
    ignored = [
        ("SF_DL 0", [0x00, 0x3E, 0x00]),
        ("SF_DL 8 on classic CAN", [0x08, 0x3E, 0x00, 0, 0, 0, 0, 0]),
        ("SF_DL above the frame length", [0x05, 0x3E, 0x00]),
        ("empty frame", []),
        ("PCI type 0x4", [0x40, 0x3E, 0x00]),
        ("PCI type 0xF", [0xF2, 0x3E, 0x00, 0, 0, 0, 0, 0]),
        ("FF_DL below 8", [0x10, 0x05, 0x22, 0xC0, 0x01, 0, 0, 0]),
        ("FF in a short frame", [0x10, 0x0A, 0x22, 0xC0]),
        ("CF without a reception", [0x21, 0x22, 0xC0, 0x01, 0, 0, 0, 0]),
        ("FC without a transmission", [0x30, 0x00, 0x00]),
        ("FC with reserved status 0x3", [0x33, 0x00, 0x00]),
    ]
    for name, data in ignored:
        raw.send(data)
        check(f"ISO-TP {name} ignored", raw.quiet(0.25))
    raw.send([0x02, 0x3E, 0x00], extended=True)
    check("ISO-TP 29-bit frame on ID 0x7A0 ignored", raw.quiet(0.25))
    raw.send([0x02, 0x3E, 0x00], arb=0x7A1)
    check("ISO-TP other CAN ID ignored", raw.quiet(0.25))
    r = raw.request([0x3E, 0x00])
    check("still answering after malformed frames (TesterPresent)", r == b"\x7E\x00", hexs(r))
    raw.send([0x02, 0x3E, 0x00, 0xAA, 0x55, 0xAA, 0x55, 0xAA])
    r = raw.response(raw.recv(1.0))
    check("SF padded with junk: padding ignored", r == b"\x7E\x00", hexs(r))

    # Segmented requests: wrong sequence number, interruption, short CF, N_Cr timeout.
    req = bytes([0x22]) + bytes([0xC0, 0x01]) * 4  # 9 bytes: FF + 1 CF
    raw.send([0x10, len(req)] + list(req[:6]))
    fc = raw.recv(1.0)
    check("FF -> flow control CTS", fc is not None and fc[0] == 0x30, hexs(fc))
    raw.send([0x22] + list(req[6:]))
    check("CF with wrong sequence number: reception aborted, no response", raw.quiet(0.3))
    raw.send([0x21] + list(req[6:]))
    check("CF after the abort is unexpected: ignored", raw.quiet(0.3))
    raw.send([0x10, len(req)] + list(req[:6]))
    raw.recv(1.0)
    raw.send([0x10, 0x09, 0x22, 0xC0, 0x04, 0xC0, 0x04, 0xC0])  # a new FF interrupts
    fc = raw.recv(1.0)
    raw.send([0x21, 0x04, 0xC0, 0x04])
    r = raw.response(raw.recv(1.0))
    check("second FF replaces the first (interrupted reception)",
          fc is not None and fc[0] == 0x30 and r is not None and r[:3] == b"\x62\xC0\x04"
          and len(r) == 4 * 11 + 1, f"{len(r or b'')} bytes")
    raw.send([0x10, len(req)] + list(req[:6]))
    raw.recv(1.0)
    raw.send([0x21, 0xC0])  # carries 1 of the 3 bytes still due
    quiet = raw.quiet(0.2)
    raw.send([0x21] + list(req[6:]))
    r = raw.response(raw.recv(1.0))
    check("CF shorter than the data due: ignored, reception continues",
          quiet and r is not None and len(r) == 1 + 4 * 11, f"{len(r or b'')} bytes")
    raw.send([0x10, len(req)] + list(req[:6]))
    raw.recv(1.0)
    t0 = time.monotonic()
    quiet = raw.quiet(1.3)
    r = raw.request([0x3E, 0x00])
    check("FF without CFs: N_Cr (1 s) aborts, then answering", quiet and r == b"\x7E\x00",
          f"{time.monotonic() - t0:.2f} s, {hexs(r)}")
    big = bytes([0x22]) + bytes([0xC0, 0x01]) * 2047  # 4095 bytes, the classic-CAN maximum
    r = raw.request(big, timeout=3.0)
    check("4095-byte request (585 CFs) -> 7F 22 13", r == b"\x7F\x22\x13", hexs(r))
    r = raw.request(bytes([0x22]) + bytes([0xC0, 0x01]) * 8)
    check("8 DIDs in one segmented request", r is not None and len(r) == 1 + 8 * 11,
          f"{len(r or b'')} bytes")
    r = raw.request(bytes([0x22]) + bytes([0xC0, 0x02]) * 8)
    k = split_rdbi(r or b"\x7F").get(0xC002, b"")
    check("8 x 0xC002 in one request: 8 intrinsics records, no 0x14",
          r is not None and r[0] == 0x62 and len(r) == 1 + 8 * (2 + len(k)), f"{len(r or b'')} bytes")

    # Flow control from the tester is honoured on a segmented response (0xC002, 41 bytes).
    raw.send([0x03, 0x22, 0xC0, 0x02])
    ff = raw.recv(1.0)
    raw.send([0x30, 2, 20])  # block size 2, STmin 20 ms
    cfs, times = [], []
    for _ in range(2):
        cfs.append(raw.recv(1.0))
        times.append(time.monotonic())
    paused = raw.quiet(0.3)
    raw.send([0x31, 0, 0])  # WAIT
    waited = raw.quiet(0.3)
    raw.send([0x30, 0, 0])
    rest = [raw.recv(1.0) for _ in range(3)]
    ok = (ff is not None and ff[:2] == b"\x10\x29" and None not in cfs and None not in rest
          and [c[0] for c in cfs + rest] == [0x21, 0x22, 0x23, 0x24, 0x25])
    check("segmented response: BS 2 pauses for FC, WAIT holds, CTS resumes", ok and paused and waited,
          f"FF {hexs(ff)}, gap {1e3 * (times[1] - times[0]):.1f} ms")
    check("segmented response: STmin 20 ms between CFs", times[1] - times[0] >= 0.018,
          f"{1e3 * (times[1] - times[0]):.1f} ms")
    raw.send([0x03, 0x22, 0xC0, 0x02])
    raw.recv(1.0)
    raw.send([0x32, 0, 0])  # overflow
    quiet = raw.quiet(0.3)
    r = raw.request([0x3E, 0x00])
    check("FC overflow aborts the response; then answering", quiet and r == b"\x7E\x00", hexs(r))
    raw.send([0x03, 0x22, 0xC0, 0x02])
    raw.recv(1.0)
    quiet = raw.quiet(1.3)  # no FC: N_Bs (1 s)
    r = raw.request([0x3E, 0x00])
    check("no FC: N_Bs aborts the response; then answering", quiet and r == b"\x7E\x00", hexs(r))

    # UDS lengths, sub-functions, unknown services and identifiers (ISO 14229-1 7.5 order).
    cases = [
        ("0x10 without sub-function", [0x10], 0x13),
        ("0x10 with an extra byte", [0x10, 0x03, 0x00], 0x13),
        ("0x10 sub-function 0x02", [0x10, 0x02], 0x12),
        ("0x10 sub-function 0x02 with SPR (NRC not suppressed)", [0x10, 0x82], 0x12),
        ("0x3E with an extra byte", [0x3E, 0x00, 0x00], 0x13),
        ("0x3E sub-function 0x01", [0x3E, 0x01], 0x12),
        ("0x22 without DID", [0x22], 0x13),
        ("0x22 odd length", [0x22, 0xC0], 0x13),
        ("0x22 odd length (3 bytes of DID)", [0x22, 0xC0, 0x01, 0xC0], 0x13),
        ("0x22 nine DIDs", [0x22] + [0xC0, 0x01] * 9, 0x13),
        ("0x22 unknown DID 0xF190", [0x22, 0xF1, 0x90], 0x31),
        ("0x11 ECUReset (not supported)", [0x11, 0x01], 0x11),
        ("0x85 (not supported)", [0x85, 0x02], 0x11),
        ("0x62 (a response SID)", [0x62, 0xC0, 0x01], 0x11),
        ("0x27 in the default session", [0x27, 0x01], 0x7F),
        ("0x31 0xC100 in the default session", [0x31, 0x01, 0xC1, 0x00], 0x7F),
        ("0x31 0xC101 in the default session", [0x31, 0x01, 0xC1, 0x01], 0x7F),
    ]
    raw.request([0x10, 0x01])
    for name, req, nrc in cases:
        r = raw.request(req)
        check(f"{name} -> 7F {req[0]:02X} {nrc:02X}", r == bytes([0x7F, req[0], nrc]), hexs(r))
    r = raw.request([0x22, 0xC0, 0x01, 0xF1, 0x90])
    check("0x22 known + unknown DID: the known one only", r is not None and len(r) == 12
          and r[:3] == b"\x62\xC0\x01", hexs(r))
    raw.send([0x02, 0x3E, 0x80])
    check("0x3E with SPR: no response", raw.quiet(0.3))
    raw.send([0x02, 0x10, 0x83])
    quiet = raw.quiet(0.3)
    r = raw.request([0x31, 0x01, 0xC1, 0x00])
    check("0x10 0x83 (SPR): no response, extended session entered", quiet
          and r == b"\x7F\x31\x33", hexs(r))
    cases = [
        ("0x31 too short", [0x31, 0x01, 0xC1], 0x13),
        ("0x31 stop (0x02, not supported)", [0x31, 0x02, 0xC1, 0x00], 0x12),
        ("0x31 unknown routine 0x1234", [0x31, 0x01, 0x12, 0x34], 0x31),
        ("0x31 0xC100 results without security", [0x31, 0x03, 0xC1, 0x00], 0x33),
        ("0x27 sub-function 0x03", [0x27, 0x03], 0x12),
        ("0x27 seed with an extra byte", [0x27, 0x01, 0x00], 0x13),
        ("0x27 key of 15 bytes", [0x27, 0x02] + [0] * 15, 0x13),
    ]
    for name, req, nrc in cases:
        r = raw.request(req)
        check(f"{name} -> 7F {req[0]:02X} {nrc:02X}", r == bytes([0x7F, req[0], nrc]), hexs(r))

    # socketcand-level junk on a second connection: refused or dropped, nothing else.
    lean = Lean(raw.port)
    lean.sock.sendall(b"no brackets at all " + b"< send 7A0 9 1 2 3 4 5 6 7 8 9 >< send ZZZ 1 0 >"
                      b"< send 7A0 3 2 3e >< frame 7A0 1.0 023E00 >< \xff\xfe >< nonsense >"
                      + b"<" + b"x" * 5000 + b">")
    lean.recv(0.3)
    lean.send([[0x02, 0x3E, 0x00]])
    frames, end = [], time.monotonic() + 2
    while not frames and time.monotonic() < end:
        frames = lean.recv(0.5)
    lean.close()
    check("socketcand junk (bad lengths, IDs, bytes, 5 kB message) ignored, connection kept",
          frames[:1] and frames[0][:2] == b"\x02\x7E", hexs(frames[0] if frames else None))
    r = raw.request([0x3E, 0x00])
    check("still answering the other connection", r == b"\x7E\x00", hexs(r))

    flood_check(raw, flood)


class Lean:
    """A minimal socketcand rawmode client (bytes in, bytes out) for the flood: python-can
    parses its receive buffer as a string, slice by slice, which caps it well below what
    the daemon answers; this one keeps the measurement about the daemon."""

    def __init__(self, port):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.buf = b""
        for command in (None, b"< open can0 >", b"< rawmode >"):
            if command:
                self.sock.sendall(command)
            want = b"< ok >" if command else b"< hi >"
            while want not in self.buf:
                self.buf += self.sock.recv(4096)
            self.buf = self.buf[self.buf.index(want) + len(want):]

    def send(self, frames):
        self.sock.sendall(b"".join(b"< send 7A0 %X %s >" % (len(f), bytes(f).hex(" ").encode())
                                   for f in frames))

    def recv(self, timeout):
        """Response frames (0x7A8) that arrived within `timeout` s (at least one if any)."""
        self.sock.settimeout(timeout)
        try:
            self.buf += self.sock.recv(1 << 16)
        except socket.timeout:
            return []
        *messages, self.buf = self.buf.split(b">")
        out = []
        for m in messages:
            w = m.split()
            if len(w) >= 4 and w[1] == b"frame" and w[2] == b"7A8":
                out.append(bytes.fromhex(w[4].decode()) if len(w) > 4 else b"")
        return out

    def close(self):
        self.sock.close()


def flood_check(raw, n, window=64):
    """n requests as fast as the daemon answers them, at most `window` in flight, mixed
    with malformed frames (dropped); every answer checked in order; the rate measured."""
    kinds = [
        ([0x02, 0x3E, 0x00], b"\x7E\x00"),
        ([0x03, 0x22, 0xF1, 0x90], b"\x7F\x22\x31"),
        ([0x02, 0x11, 0x01], b"\x7F\x11\x11"),
        ([0x02, 0x22, 0xC0], b"\x7F\x22\x13"),
    ]
    junk = [[0x00, 0x3E], [0x21, 1, 2, 3], [0x30, 0, 0], [0x4F]]
    raw.close()  # a rawmode client sees every frame: python-can would only fall behind
    lean = Lean(raw.port)
    expected, sent, got, bad = [], 0, 0, 0
    t0 = time.monotonic()
    while got < n:
        batch = []
        while sent < n and sent - got < window:
            frame, answer = kinds[sent % len(kinds)]
            batch.append(frame)
            expected.append(answer)
            if sent % 10 == 9:
                batch.append(junk[(sent // 10) % len(junk)])
            sent += 1
        if batch:
            lean.send(batch)
        frames = lean.recv(2.0)
        if not frames:  # nothing for 2 s: whatever is in flight is lost
            break
        for f in frames:
            r = f[1:1 + (f[0] & 0x0F)] if f and f[0] >> 4 == 0 else None
            bad += got >= len(expected) or r != expected[got]
            got += 1
    dt = time.monotonic() - t0
    lean.close()
    raw.bus = open_bus(raw.port)
    check(f"flood: {n} requests (+{n // 10} malformed frames), every answer right and in order",
          got == n and bad == 0, f"{got} answers, {bad} wrong, {sent - got} lost")
    print(f"RATE flood, {window} in flight: {got} requests in {dt:.2f} s = {got / dt:.0f} requests/s",
          flush=True)
    m = min(2000, n)
    t0 = time.monotonic()
    ok = 0
    for i in range(m):
        raw.send([0x02, 0x3E, 0x00])
        ok += (raw.recv(1.0) or b"")[:3] == b"\x02\x7E\x00"
    dt = time.monotonic() - t0
    check(f"closed loop (python-can): {m} TesterPresent round trips", ok == m, f"{ok} answered")
    print(f"RATE closed loop (python-can), one in flight: {m / dt:.0f} requests/s "
          f"({1e6 * dt / m:.0f} us per round trip)", flush=True)


def wait_port(port, timeout):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return True
        except OSError:
            time.sleep(0.2)
    return False


def run(args):
    secret = open(args.secret_file, "rb").read()
    if secret.endswith(b"\n"):
        secret = secret[:-1]
    store = args.store
    seeded = current(store)[0]

    # 1. Every DID in the default session, against the seeded generation.
    uds = Uds(args.port, secret)
    c = uds.client
    check_dids("before any run", uds.read_all(), store, (0, 1))
    r = uds.raw([0x22, 0xC0, 0x01, 0xC0, 0x02, 0xC0, 0x03, 0xC0, 0x04])
    together, alone = (split_rdbi(r) if r and r[0] == 0x62 else {}), uds.read_all()
    # The state byte may move (idle -> room seen) between the reads; the rest may not.
    check("four DIDs in one request = one at a time",
          together.keys() == set(DIDS) and together[0xC001][1:] == alone[0xC001][1:]
          and all(together[d] == alone[d] for d in DIDS[1:]), f"{len(r or b'')} bytes")

    # 2. Sessions and security: routines need the extended session and SecurityAccess.
    uds.expect_nrc("0xC100 start in the default session -> 0x7F", lambda: c.start_routine(0xC100), 0x7F)
    uds.expect_nrc("0x27 seed in the default session -> 0x7F", lambda: c.request_seed(1), 0x7F)
    t = c.change_session(3).service_data
    check("0x10 extended: P2 50 ms, P2* 5000 ms",
          abs(t.p2_server_max - 0.05) < 1e-9 and abs(t.p2_star_server_max - 5.0) < 1e-9,
          f"{t.p2_server_max} s, {t.p2_star_server_max} s")
    uds.expect_nrc("0xC100 start without security -> 0x33", lambda: c.start_routine(0xC100), 0x33)
    uds.expect_nrc("0xC101 rollback without security -> 0x33", lambda: c.start_routine(0xC101), 0x33)
    r = uds.raw([0x27, 0x02] + [0] * 16)
    check("0x27 key before a seed -> 0x24", r == b"\x7F\x27\x24", hexs(r))
    seed = c.request_seed(1).service_data.seed
    check("0x27 seed: 16 bytes, not all zero", len(seed) == 16 and any(seed), hexs(seed))
    seed2 = c.request_seed(1).service_data.seed
    check("0x27 seeds differ between requests", seed2 != seed)
    r = uds.raw([0x27, 0x02] + list(key_for(seed, secret)))
    check("0x27 key for an earlier seed -> 0x35", r == b"\x7F\x27\x35", hexs(r))
    c.config["security_algo_params"] = b"wrong secret"
    uds.expect_nrc("wrong key -> 0x35", lambda: c.unlock_security_access(1), 0x35)
    uds.expect_nrc("0xC100 start after a wrong key -> 0x33", lambda: c.start_routine(0xC100), 0x33)
    uds.expect_nrc("0xC101 rollback after a wrong key -> 0x33", lambda: c.start_routine(0xC101), 0x33)
    uds.expect_nrc("third wrong key in a row -> 0x36", lambda: c.unlock_security_access(1), 0x36)
    locked_at = time.monotonic()
    uds.expect_nrc("seed while locked -> 0x37", lambda: c.request_seed(1), 0x37)
    uds.close()

    # 3. Robustness while the lock runs (raw frames; the lock outlives session changes).
    raw = RawTp(args.port)
    robustness(raw, args.flood)
    raw.request([0x10, 0x03])
    r = raw.request([0x27, 0x01])
    left = LOCKOUT_S - (time.monotonic() - locked_at)
    if left > 0.2:
        check("seed still refused while the lock runs -> 0x37", r == b"\x7F\x27\x37",
              f"{hexs(r)}, {left:.1f} s left")
    time.sleep(max(0.0, left + 0.3))
    raw.close()

    # 4. Unlock, start a calibration, wait for it (0x78 responsePending), check the store.
    uds = Uds(args.port, secret)
    c = uds.client
    c.change_session(3)
    c.config["security_algo_params"] = secret
    try:
        c.unlock_security_access(1)
        check("unlocked with the HMAC key after the lock expired", True)
    except Exception as e:  # noqa: BLE001
        check("unlocked with the HMAC key after the lock expired", False, str(e))
    r = uds.raw([0x27, 0x01])
    check("0x27 seed when unlocked: all zeros", r == b"\x67\x01" + bytes(16), hexs(r))
    uds.expect_nrc("0xC100 results before any run -> 0x24", lambda: c.get_routine_result(0xC100), 0x24)
    uds.close()

    raw = RawTp(args.port)
    raw.send([0x04, 0x31, 0x01, 0xC1, 0x00])
    t0 = time.monotonic()
    first = raw.recv(1.0)
    check("0xC100 start: first answer 0x78 within P2", first is not None
          and first[:4] == b"\x03\x7F\x31\x78", f"{hexs(first)} after {1e3 * (time.monotonic() - t0):.0f} ms")
    r = raw.request([0x22, 0xC0, 0x01], timeout=1.0)
    check("request while the run is pending -> 7F 22 21", r == b"\x7F\x22\x21", hexs(r))
    pendings, gaps, final, last = 0, [], None, time.monotonic()
    while final is None:
        f = raw.recv(6.0)
        now = time.monotonic()
        if f is None:
            break
        gaps.append(now - last)
        last = now
        msg = raw.response(f)
        if msg == b"\x7F\x31\x78":
            pendings += 1
        else:
            final = msg
    took = time.monotonic() - t0
    check("0x78 repeated within P2* (5 s) while the run goes on", all(g < 5.0 for g in gaps),
          f"{pendings} more 0x78, longest gap {max(gaps or [0]):.2f} s, run {took:.1f} s")
    rec, _ = current(store)
    want = bytes([0x71, 0x01, 0xC1, 0x00, 4]) + (seeded["generation"] + 1).to_bytes(4, "big")
    check("0xC100 final answer: accepted, generation +1", final == want, hexs(final))
    check("store: new generation in current.json and history",
          rec["generation"] == seeded["generation"] + 1 and "restored_from" not in rec
          and os.path.exists(os.path.join(store, "history", f"gen-{rec['generation']:06d}.json")),
          f"generation {rec['generation']}")
    check("store: the new calibration differs from the seeded one",
          rec["camera"]["fx"] != seeded["camera"]["fx"]
          and rec["lidar_to_camera"]["translation"] != seeded["lidar_to_camera"]["translation"],
          f"fx {seeded['camera']['fx']:.3f} -> {rec['camera']['fx']:.3f}")
    r = raw.request([0x31, 0x03, 0xC1, 0x00])
    check("0xC100 results = the final answer", r == b"\x71\x03" + want[2:], hexs(r))
    raw.close()

    uds = Uds(args.port, secret)
    c = uds.client
    records = uds.read_all()
    check_dids("after the run", records, store, (4,))
    check_sensor_dids("after the run", uds, records)

    # 5. Roll back: a new generation restoring the one before the run.
    before = rec
    try:
        got = c.start_routine(0xC101).service_data.routine_status_record
        detail = hexs(got)
    except Exception as e:  # noqa: BLE001
        got, detail = None, f"{type(e).__name__}: {e}"
    rec, _ = current(store)
    check("0xC101 rollback: positive, generation in force returned",
          got == (before["generation"] + 1).to_bytes(4, "big"), detail)
    prev = history(store, seeded["generation"])
    check("store: rollback wrote generation +1 restoring the previous one",
          rec["generation"] == before["generation"] + 1
          and rec.get("restored_from") == seeded["generation"]
          and rec["camera"] == prev["camera"] and rec["lidar_to_camera"] == prev["lidar_to_camera"]
          and rec["quality"] == prev["quality"],
          f"generation {rec['generation']}, restored_from {rec.get('restored_from')}")
    check_dids("after the rollback", uds.read_all(), store, (4,))
    uds.expect_nrc("0xC101 again, nothing older -> 0x22", lambda: c.start_routine(0xC101), 0x22)
    uds.expect_nrc("0xC101 results (not supported) -> 0x12", lambda: c.get_routine_result(0xC101), 0x12)

    # 6. S3: tester present keeps the session; silence ends it (and relocks).
    for _ in range(4):
        time.sleep(1.5)
        uds.raw([0x3E, 0x80], timeout=0.01)  # suppressed: no answer expected
    r = uds.raw([0x31, 0x03, 0xC1, 0x00])
    check("S3: 6 s of suppressed TesterPresent keep the unlocked extended session",
          r is not None and r[:4] == b"\x71\x03\xC1\x00", hexs(r))
    time.sleep(S3_S + 0.5)
    uds.expect_nrc("S3: 5.5 s of silence -> default session, routine -> 0x7F",
                   lambda: c.start_routine(0xC100), 0x7F)
    uds.close()


def main():
    # python-can logs every TCP read that splits a message; only errors matter here.
    logging.getLogger("can").setLevel(logging.ERROR)
    # udsoncan logs every negative response as an error; here they are expected results.
    logging.getLogger("UdsClient").setLevel(logging.CRITICAL)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed-store", metavar="DIR", help="write generation 1 into DIR and exit")
    ap.add_argument("--port", type=int, help="the daemon's socketcand endpoint on 127.0.0.1")
    ap.add_argument("--store", help="the daemon's store directory")
    ap.add_argument("--secret-file", help="the daemon's secret file")
    ap.add_argument("--flood", type=int, default=10000, help="requests in the flood (10000)")
    ap.add_argument("--wait", type=float, default=30.0, help="seconds to wait for the port")
    args = ap.parse_args()
    if args.seed_store:
        seed_store(args.seed_store)
        return 0
    if not (args.port and args.store and args.secret_file):
        ap.error("--port, --store and --secret-file are needed")
    if not wait_port(args.port, args.wait):
        print(f"FAIL nothing listens on 127.0.0.1:{args.port}")
        return 1
    t0 = time.monotonic()
    try:
        run(args)
    except Exception as e:  # noqa: BLE001 (report, count as a failure)
        import traceback
        traceback.print_exc()
        check("the checks ran to the end", False, f"{type(e).__name__}: {e}")
    passed = sum(RESULTS)
    print(f"{passed} passed, {len(RESULTS) - passed} failed ({time.monotonic() - t0:.0f} s)")
    return 0 if RESULTS and passed == len(RESULTS) else 1


if __name__ == "__main__":
    sys.exit(main())
