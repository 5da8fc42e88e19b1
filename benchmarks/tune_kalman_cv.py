"""Choose srp-kalman-cv's defaults (q, r) on a development set, never on the test tasks.

The development set is walking talkers around a turned static NAO array (dev-walk) and heard by a
moving, turning head (dev-turn): the scene models of sim-walk and sim-turn, but LibriSpeech
train-clean-100 speech and other seeds (777000, 777001), 12 episodes each. Prints one row per
configuration: RMSAE all frames, voice-active frames and lag (s) on each set.

    nice -n 10 .venv/bin/python benchmarks/tune_kalman_cv.py --librispeech ../shared/data/LibriSpeech
"""
from __future__ import annotations

import argparse
import itertools
import json

import doabench
from doabench.envs.registry import register_task

SETS = {
    "dev-walk": {},
    "dev-turn": {"array_motion_p": 1.0, "array_speed": [0.0, 0.3]},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--librispeech", default=None, help="LibriSpeech root holding train-clean-100")
    ap.add_argument("--episodes", type=int, default=12)
    args = ap.parse_args()
    for i, (name, extra) in enumerate(SETS.items()):
        register_task({"id": name, "version": 1, "kind": "simulated", "array": "nao", "episodes": args.episodes,
                       "base_seed": 777000 + i, "speech": {"corpus": "librispeech", "subset": "train-clean-100"},
                       "scene": {"duration_s": 20.0, "walk_p": 1.0, "array_yaw": [-180.0, 180.0],
                                 "array_pitch": [-30.0, 30.0], "pause_p": 0.5, "pause_count": [1, 2],
                                 "pause_s": [1.0, 3.0], "pause_after_s": 2.0, **extra}})
    configs = [("srp-max:32x64", {}), ("srp-kalman:32x64", {})] + [
        ("srp-kalman-cv:32x64", {"q": q, "r": r}) for q, r in itertools.product([0.001, 0.003, 0.01, 0.03], [0.02, 0.05, 0.15])]
    print("| tracker | options | " + " | ".join(f"{s} all | {s} voice | {s} lag s" for s in SETS) + " |")
    print("|---|---|" + "---|---|---|" * len(SETS))
    for tracker, opts in configs:
        cells = []
        for task in SETS:
            res = doabench.run(tracker=tracker, task=task, tracker_options=opts, progress=False, keep_frames=False,
                               librispeech=args.librispeech)
            s = res["summary"]
            cells += [f"{s['rmsae_all']:.2f}", f"{s['rmsae_nonsilent']:.2f}", str(s["lag_s"])]
        print(f"| {tracker} | {json.dumps(opts)} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
