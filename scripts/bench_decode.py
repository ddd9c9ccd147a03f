#!/usr/bin/env python3
"""Decode-throughput comparison on the VLP-16 capture: roomcal (the `lidar_decode` bench,
release build) against the `velodyne-decoder` PyPI package (C++ core), both decoding every
packet of the same capture into a cloud, on one core, in interleaved rounds. Prints each
decoder's CPU time per pass (and best wall time: the machine may be shared), the multiple of
the sensor's real-time rate, and the ratios. Not needed by `cargo test`.

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


def bench_velodyne_decoder(pcap, reps, batches=10):
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
    # The whole capture in one C++ call per pass: no per-packet Python overhead. Best wall
    # batch and CPU time, as the Rust bench measures itself.
    batch = max(1, -(-reps // batches))
    best, cpu0 = float("inf"), time.thread_time()
    for _ in range(batches):
        start = time.perf_counter()
        for _ in range(batch):
            _, cloud = decoder.decode(packets)
        best = min(best, (time.perf_counter() - start) / batch)
    cpu = (time.thread_time() - cpu0) / (batch * batches)
    span = frames[-1][0] - frames[0][0]
    return {"decoder": "velodyne-decoder " + vd.__version__, "packets": len(packets),
            "points": len(cloud), "capture_s": span, "decode_s": best, "cpu_s": cpu,
            "real_time_multiple": span / cpu}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pcap", nargs="?", default=DEFAULT_PCAP)
    ap.add_argument("--reps", type=int, default=50)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    if not os.path.exists(args.pcap):
        print(f"skipped: {args.pcap} is absent")
        return
    # Interleaved rounds, the best of each: the machine may be shared.
    ours, theirs = [], []
    for _ in range(args.rounds):
        ours.append(bench_roomcal(args.pcap, args.reps * 4))
        theirs.append(bench_velodyne_decoder(args.pcap, args.reps))
    ours = min(ours, key=lambda r: r["cpu_s"])
    theirs = min(theirs, key=lambda r: r["cpu_s"])
    for r in (ours, theirs):
        print(json.dumps(r))
    if ours["points"] != theirs["points"]:
        print(f"warning: {ours['points']} points vs {theirs['points']}")
    for name, r in (("roomcal", ours), ("velodyne-decoder", theirs)):
        print(f"{name}: {r['cpu_s'] * 1e3:.3f} ms CPU per pass ({r['decode_s'] * 1e3:.3f} ms best "
              f"wall), {r['real_time_multiple']:.0f}x the sensor's real time on one core")
    print(f"ratio (velodyne-decoder time / roomcal time): CPU {theirs['cpu_s'] / ours['cpu_s']:.2f}, "
          f"best wall {theirs['decode_s'] / ours['decode_s']:.2f}")


if __name__ == "__main__":
    main()
