"""Peak memory of ``doabench track`` and ``doabench features`` on a long recording.

Writes a ``--minutes``-long (default 10) ``--channels``-channel (default 12, the NAO array)
16 kHz 16-bit WAV of white noise with a louder noise burst every other second (so the VAD has
something to find) into a temporary folder, written block by block, then runs each command in
its own Python subprocess and reports that subprocess's peak resident set size
(``resource.getrusage(RUSAGE_SELF).ru_maxrss``, read at its exit) and its wall time.

    nice -n 10 .venv/bin/python benchmarks/bench_track_memory.py
    nice -n 10 .venv/bin/python benchmarks/bench_track_memory.py --minutes 1   # quicker

Not a test: the numbers depend on the machine (the torch import alone is a few hundred MB).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

FS = 16000

CHILD = """
import json, resource, sys, time
from doabench.cli.main import main
t = time.perf_counter()
rc = main(sys.argv[1:])
print(json.dumps({"rc": rc, "wall_s": time.perf_counter() - t,
                  "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def write_recording(path: Path, minutes: float, channels: int, seed: int = 0) -> int:
    """White noise, louder every other second, written in 10 s blocks; returns the sample count."""
    import soundfile as sf

    rng = np.random.default_rng(seed)
    total = int(minutes * 60 * FS)
    block = 10 * FS
    with sf.SoundFile(str(path), "w", FS, channels, subtype="PCM_16") as f:
        for start in range(0, total, block):
            n = min(block, total - start)
            t = (start + np.arange(n)) // FS
            gain = np.where(t % 2 == 0, 0.3, 0.01)[:, None]
            f.write((rng.standard_normal((n, channels)) * gain).clip(-1, 1).astype(np.float32))
    return total


def measure(argv: list[str]) -> dict:
    proc = subprocess.run([sys.executable, "-c", CHILD, *argv], capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--channels", type=int, default=12)
    ap.add_argument("--tracker", default="srp-max")
    ap.add_argument("--kind", default="srp", help="doabench features --kind (default: srp)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "long.wav"
        n = write_recording(rec, args.minutes, args.channels)
        print(f"{args.minutes:g} min x {args.channels} channels at {FS} Hz: {rec.stat().st_size / 2**20:.0f} MiB "
              f"PCM_16 ({n * args.channels * 4 / 2**20:.0f} MiB as float32)")
        runs = {
            f"track --tracker {args.tracker}": ["track", str(rec), "--tracker", args.tracker,
                                                "--out", str(Path(tmp) / "track.csv")],
            f"features --kind {args.kind}": ["features", str(rec), "--kind", args.kind,
                                             "--out", str(Path(tmp) / "feats.npy")],
        }
        for name, argv in runs.items():
            r = measure(argv)
            print(f"{name:32s} peak RSS {r['maxrss_mb']:7.0f} MiB   wall {r['wall_s']:6.1f} s")
    load = " ".join(f"{x:.2f}" for x in __import__("os").getloadavg())
    print(f"load average {load}; {time.strftime('%Y-%m-%d')}")


if __name__ == "__main__":
    main()
