#!/usr/bin/env python3
"""roomcal's Velodyne decode, in each of its conventions (`--velodyne-interpolation manual`,
`nebula`), against the `velodyne-decoder` PyPI package on ../shared/data's VLP-16 and
VLP-32C captures: point by point, the median, p99 and largest distance between the two
decoders' points, per capture and convention. Not needed by `cargo test`.

    python3 -m venv target/velodyne-venv
    target/velodyne-venv/bin/pip install -r scripts/requirements-velodyne.txt
    cargo build --release
    target/velodyne-venv/bin/python scripts/compare_velodyne.py [--bin target/release/roomcal]

Pairing. roomcal's PCD holds every non-zero return in packet, block, channel order (the
second echo of a dual-return firing dropped when it repeats the first); this script walks
the capture's packets the same way to give each PCD point its packet, firing sequence,
firing slot and laser (and checks the laser against the PCD's ring and the counts).
velodyne-decoder gives each point its time and its ring (lasers sorted by elevation).
Both sides are then sorted by firing time, ring and range and paired in that order; the
laser → ring map is the majority over the two clouds in their given order, and every pair's
ring must agree with it (`ring agreement` is printed: anything under 1 means the pairing
failed, and the distances mean nothing).
"""
import argparse
import importlib.metadata
import os
import struct
import subprocess
import sys
import tempfile
from collections import Counter

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "..", "shared", "data", "pcap")
# capture folder, roomcal model, velodyne-decoder model, calibration file
CAPTURES = [
    ("velodyne-vlp16", "vlp16", "VLP16", "VLP16.yaml"),
    ("velodyne-vlp32c", "vlp32c", "VLP32C", "VLP32.yaml"),
]
CONVENTIONS = ["manual", "nebula"]
PACKET_LEN, DUAL = 1206, 0x39


def read_pcd(path, np):
    """x y z intensity ring of a binary PCD written by `roomcal decode`."""
    data = open(path, "rb").read()
    start = data.index(b"DATA binary\n") + len(b"DATA binary\n")
    dtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "<u2")])
    return np.frombuffer(data[start:], dtype=dtype)


def data_packets(path):
    """The Velodyne data packets (UDP payloads of 1206 bytes) of a classic Ethernet pcap."""
    data, off, out = open(path, "rb").read(), 24, []
    while off + 16 <= len(data):
        incl = struct.unpack_from("<IIII", data, off)[2]
        payload = data[off + 16 + 42 : off + 16 + incl]
        if len(payload) == PACKET_LEN:
            out.append(payload)
        off += 16 + incl
    return out


def roomcal_keys(packets, model):
    """(packet, firing sequence, firing slot, laser) of every return, in roomcal's order."""
    keys = []
    for k, p in enumerate(packets):
        dual, previous = p[1204] == DUAL, None
        for b in range(12):
            block = p[b * 100 : (b + 1) * 100]
            for c in range(32):
                raw = block[4 + 3 * c] | block[5 + 3 * c] << 8
                repeated = dual and b % 2 == 1 and (previous[4 + 3 * c] | previous[5 + 3 * c] << 8) == raw
                if raw == 0 or repeated:
                    continue
                sequence_block = b // 2 if dual else b
                if model == "vlp16":  # two firings of 16 lasers per block
                    keys.append((k, 2 * sequence_block + c // 16, c % 16, c % 16))
                else:  # one firing per block, lasers in pairs
                    keys.append((k, sequence_block, c // 2, c))
            previous = block
    return keys


def packets_with_a_jump(packets):
    """Packets whose block azimuths (or the step to the next packet) jump by more than 5°:
    a capture with a gap (the VLP-32C set holds only the front half of each turn). There the
    decoders' conventions for the advance legitimately differ; the rest is the comparison."""
    azimuth = lambda p, b: struct.unpack_from("<H", p, b * 100 + 2)[0]
    jumps = set()
    for k, p in enumerate(packets):
        steps = [azimuth(p, b + 1) - azimuth(p, b) for b in range(11)]
        if k + 1 < len(packets):
            steps.append(azimuth(packets[k + 1], 0) - azimuth(p, 11))
        if any(s % 36000 > 500 for s in steps):
            jumps.add(k)
    return jumps


def stats(np, d):
    return (f"median {1e3 * np.median(d):.2f} mm, p99 {1e3 * np.percentile(d, 99):.2f} mm, "
            f"max {1e3 * d.max():.1f} mm, {np.sum(d > 0.02)} points > 20 mm")


def compare(np, vd, binary, folder, model, vd_model, calibration, convention):
    here = os.path.join(DATA, folder)
    pcap, cal = os.path.join(here, folder + ".pcap"), os.path.join(here, calibration)
    with tempfile.TemporaryDirectory() as tmp:
        pcd = os.path.join(tmp, "cloud.pcd")
        subprocess.run([binary, "decode", "--lidar", model, "--calibration", cal,
                        "--velodyne-interpolation", convention, pcap, "--out", pcd],
                       check=True, capture_output=True)
        ours = read_pcd(pcd, np)
    packets = data_packets(pcap)
    keys = roomcal_keys(packets, model)
    if len(keys) != len(ours) or any(k[3] != r for k, r in zip(keys, ours["ring"].tolist())):
        sys.exit(f"{folder}: this script's walk of the capture does not give roomcal's points")
    config = vd.Config(model=getattr(vd.Model, vd_model), calibration=vd.Calibration.read(cal),
                       min_range=0.0, max_range=10000.0)
    scans = list(vd.read_pcap(pcap, config))
    # Columns x y z intensity time column ring return_type, plus the time from the first scan.
    t0 = scans[0][0].device
    theirs = np.concatenate([np.column_stack([c, (stamp.device - t0) + c[:, 4].astype(float)])
                             for stamp, c in scans])
    if len(theirs) != len(ours):
        return f"{len(ours)} points, velodyne-decoder {len(theirs)}: not paired"
    n = len(ours)
    votes = {}
    for laser, ring in zip(ours["ring"].tolist(), theirs[:, 6].astype(int).tolist()):
        votes.setdefault(laser, Counter())[ring] += 1
    ring_of = {laser: c.most_common(1)[0][0] for laser, c in votes.items()}
    xyz = np.stack([ours["x"], ours["y"], ours["z"]], 1).astype(float)
    our_range = np.linalg.norm(xyz, axis=1)
    order = sorted(range(n), key=lambda i: (*keys[i][:3], ring_of[keys[i][3]], our_range[i]))
    their_range = np.linalg.norm(theirs[:, :3].astype(float), axis=1)
    their_order = np.lexsort((their_range, theirs[:, 6], np.round(theirs[:, 8] * 1e7)))
    rings_agree = np.mean(np.array([ring_of[keys[i][3]] for i in order]) == theirs[their_order, 6])
    d = np.linalg.norm(xyz[order] - theirs[their_order, :3].astype(float), axis=1)
    jumps = packets_with_a_jump(packets)
    steady = np.array([keys[i][0] not in jumps for i in order])
    return (f"{n} points, ring agreement {rings_agree:.4f}: all: {stats(np, d)}; "
            f"without the {len(jumps)} packets at an azimuth jump ({np.sum(steady)} points): "
            f"{stats(np, d[steady])}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "roomcal"))
    args = ap.parse_args()
    if not os.path.isdir(DATA):
        print(f"skipped: {DATA} is absent")
        return
    import numpy as np
    import velodyne_decoder as vd

    # The distribution's version: 3.1.0's module still reports __version__ 3.0.0.
    version = importlib.metadata.version("velodyne-decoder")
    print(f"roomcal ({args.bin}) against velodyne-decoder {version}")
    for folder, model, vd_model, calibration in CAPTURES:
        for convention in CONVENTIONS:
            result = compare(np, vd, args.bin, folder, model, vd_model, calibration, convention)
            print(f"{folder} {convention}: {result}")


if __name__ == "__main__":
    main()
