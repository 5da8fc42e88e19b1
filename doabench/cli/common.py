"""Options shared by several subcommands."""
from __future__ import annotations

import argparse


def add_tracker_options(p: argparse.ArgumentParser, required: bool = True, default: str | None = None) -> None:
    p.add_argument("--tracker", required=required, default=default,
                   help="tracker id (srp-max, srp-max:32x64, cross3d:16x32) or package.module:Class[:spec]")
    p.add_argument("--tracker-opt", action="append", default=[], metavar="KEY=VALUE",
                   help="option passed to the tracker's constructor (repeatable), e.g. weights=FILE")


def add_corpus_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--librispeech", help="LibriSpeech root (default: $DOABENCH_LIBRISPEECH)")
    p.add_argument("--locata-root", help="LOCATA corpus root (default: $DOABENCH_LOCATA)")
    p.add_argument("--split", choices=["dev", "eval"], help="LOCATA split (default: the task's, dev)")
    p.add_argument("--backend", default="builtin", help="room simulator: builtin, pyroomacoustics or gpurir")
    p.add_argument("--device", default=None, help="cpu or cuda (default cpu)")


def corpus_kwargs(args: argparse.Namespace) -> dict:
    out = {"backend": args.backend}
    if args.librispeech:
        out["librispeech"] = args.librispeech
    if args.locata_root:
        out["locata_root"] = args.locata_root
    if args.split:
        out["split"] = args.split
    return out
