"""Check the Cross3D targets on sim-grid from committed results files and print a Markdown table.

Targets (project issue on Cross3D): the shipped 8x16 model has a lower all-frames RMSAE than
srp-max:8x16 in every cell with T60 >= 0.3 s, and lower than srp-max:32x64 in every cell with
T60 >= 0.9 s. Usage: python scripts/cross3d_targets.py [results/]
"""
import json
import sys
from pathlib import Path


def cells(folder: Path, stem: str) -> tuple[dict, dict]:
    r = json.loads((folder / f"sim-grid__{stem}.json").read_text())
    return r["cells"], r


def main(folder: Path) -> None:
    model, res = cells(folder, "cross3d_8x16")
    srp8, _ = cells(folder, "srp-max_8x16")
    srp32, _ = cells(folder, "srp-max_32x64")
    print(f"cross3d:8x16 weights {res['tracker']['weights_hash'][:12]}, commit "
          f"{res['environment']['git']['commit'][:8]}, {res['task']['episodes_run']} episodes\n")
    print("| cell | Cross3D 8x16 | srp-max 8x16 | srp-max 32x64 | beats 8x16 (T60 >= 0.3) | beats 32x64 (T60 >= 0.9) |")
    print("|---|---|---|---|---|---|")
    missed = []
    for cell, c in model.items():
        a, b, d = c["rmsae_all"], srp8[cell]["rmsae_all"], srp32[cell]["rmsae_all"]
        t1 = ("yes" if a < b else "NO") if c["t60"] >= 0.3 else "-"
        t2 = ("yes" if a < d else "NO") if c["t60"] >= 0.9 else "-"
        missed += [f"{cell} vs srp-max:8x16 by {a - b:.2f} deg"] if t1 == "NO" else []
        missed += [f"{cell} vs srp-max:32x64 by {a - d:.2f} deg"] if t2 == "NO" else []
        lo, hi = c["rmsae_all_ci95"]
        print(f"| {cell} | {a:.2f} [{lo:.1f}, {hi:.1f}] | {b:.2f} | {d:.2f} | {t1} | {t2} |")
    print("\nmissed: " + ("; ".join(missed) if missed else "none"))


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "results"))
