"""``doabench export --tracker ID --format onnx --out FILE``: deploy a learned tracker's network."""
from __future__ import annotations

import argparse

from doabench.cli.common import add_tracker_options, check_output_file, make_checked_tracker


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="export a learned tracker's network (ONNX)",
                       description="Write the full-sequence network of a learned tracker as ONNX: input = the "
                                   "network input of a whole episode (frame axis 2, batch and frames dynamic), "
                                   "output = directions (batch, frames, 3). Verified against onnxruntime when it "
                                   "is installed (pip install 'doabench[onnx]').")
    add_tracker_options(p)
    p.add_argument("--format", choices=["onnx"], default="onnx", help="export format (onnx)")
    p.add_argument("--out", required=True, help="output file, e.g. cross3d-8x16.onnx")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from doabench.cli.weights_text import weights_label
    from doabench.export_onnx import export_onnx
    from doabench.trackers.registry import parse_options

    check_output_file(args.out)
    # An untrained model is exported only with weights=random.
    tracker = make_checked_tracker(args.tracker, parse_options(args.tracker_opt))
    info = export_onnx(tracker, args.out, tracker_id=args.tracker)
    check = ("not verified (install onnxruntime: pip install 'doabench[onnx]')" if info["max_abs_diff"] is None
             else f"verified with onnxruntime (max |difference| {info['max_abs_diff']:.2e})")
    record = tracker.describe()
    # the weights by name (or file) and hash: `--tracker cross3d` alone does not say which ran
    weights = weights_label(record) or "no learned weights"
    digest = record.get("weights_hash")
    if digest and record.get("weights_name"):
        weights += f" (sha256 {str(digest)[:12]})"
    print(f"wrote {args.out}: {args.tracker}, {weights}, example input {list(info['input_shape'])} "
          f"(frame axis 2 dynamic); {check}")
    return 0
