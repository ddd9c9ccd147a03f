#!/usr/bin/env python3
"""Decode-throughput comparison on the VLP-16 capture: roomcal (the `lidar_decode` bench,
release build) against the `velodyne-decoder` PyPI package (C++ core), both decoding every
packet of the same capture on one core. Prints each decoder's time per pass, the multiple of
real time, and the ratio. Not needed by `cargo test`.

    pip install velodyne-decoder
    python3 scripts/bench_decode.py [PCAP] [--reps N]
"""
import argparse
import json
import os
import struct
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_PCAP = os.path.join(ROOT, "..", "shared", "data", "pcap", "velodyne-vlp16", "velodyne-vlp16.pcap")


def udp_payloads(path):
    """(host time, UDP payload) of each frame of a classic little-endian Ethernet pcap."""
    data = open(path, "rb").read()
    out, off = [], 24
    while off + 16 <= len(data):
        sec, usec, incl, _ = struct.unpack_from("<IIII", data, off)
        out.append((sec + usec * 1e-6, data[off + 16 + 42 : off + 16 + incl]))
        off += 16 + incl
    return out


def bench_roomcal(pcap, reps):
    cmd = ["cargo", "bench", "--quiet", "--bench", "lidar_decode", "--", pcap, "vlp16", str(reps)]
    # One core, as for the Python decoder.
    if sys.platform.startswith("linux"):
        cmd = ["taskset", "-c", "0"] + cmd
    out = subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, text=True).stdout
    return json.loads(next(line for line in out.splitlines() if line.startswith("{")))


def bench_velodyne_decoder(pcap, reps):
    import velodyne_decoder as vd

    if sys.platform.startswith("linux"):
        os.sched_setaffinity(0, {0})
    frames = udp_payloads(pcap)
    packets = vd.PacketVector()
    for t, p in frames:
        if len(p) == 1206:
            packets.append(vd.VelodynePacket(t, list(p)))
    config = vd.Config(model=vd.Model.VLP16, min_range=0.0, max_range=1000.0)
    decoder = vd.ScanDecoder(config)
    # The whole capture in one C++ call per pass: no per-packet Python overhead.
    start = time.perf_counter()
    for _ in range(reps):
        _, cloud = decoder.decode(packets)
    per_pass = (time.perf_counter() - start) / reps
    span = frames[-1][0] - frames[0][0]
    return {"decoder": "velodyne-decoder " + vd.__version__, "packets": len(packets),
            "points": len(cloud), "capture_s": span, "decode_s": per_pass,
            "real_time_multiple": span / per_pass}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pcap", nargs="?", default=DEFAULT_PCAP)
    ap.add_argument("--reps", type=int, default=50)
    args = ap.parse_args()
    if not os.path.exists(args.pcap):
        print(f"skipped: {args.pcap} is absent")
        return
    ours = bench_roomcal(args.pcap, args.reps * 4)
    theirs = bench_velodyne_decoder(args.pcap, args.reps)
    for r in (ours, theirs):
        print(json.dumps(r))
    print(f"roomcal: {ours['decode_s'] * 1e3:.3f} ms per pass, {ours['real_time_multiple']:.0f}x real time")
    print(f"velodyne-decoder: {theirs['decode_s'] * 1e3:.3f} ms per pass, "
          f"{theirs['real_time_multiple']:.0f}x real time")
    print(f"ratio (velodyne-decoder time / roomcal time): {theirs['decode_s'] / ours['decode_s']:.2f}")


if __name__ == "__main__":
    main()
