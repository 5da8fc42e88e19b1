"""``doabench data download librispeech --subset S [--dest DIR]``: fetch corpora."""
from __future__ import annotations

import argparse

from doabench.corpora.speech import LIBRISPEECH_SUBSETS


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("data", help="download corpora (LibriSpeech)",
                       description="Download corpora used by simulated tasks.")
    data_sub = p.add_subparsers(dest="data_command", metavar="ACTION")
    d = data_sub.add_parser(
        "download", help="download and unpack a corpus",
        description="Download an official LibriSpeech subset from OpenSLR (resource 12), resuming an "
                    "interrupted download, checking the published MD5 and unpacking atomically into "
                    "DEST/LibriSpeech/SUBSET. Then pass --librispeech DEST/LibriSpeech or set "
                    "DOABENCH_LIBRISPEECH.")
    d.add_argument("corpus", choices=["librispeech"], help="corpus to download")
    d.add_argument("--subset", required=True, choices=LIBRISPEECH_SUBSETS, help="official subset")
    d.add_argument("--dest", default="data", help="destination folder (default: ./data)")
    d.add_argument("--base-url", default=None,
                   help="mirror holding SUBSET.tar.gz (default https://www.openslr.org/resources/12; "
                        "e.g. https://us.openslr.org/resources/12)")
    d.add_argument("--keep-archive", action="store_true", help="keep the .tar.gz after unpacking")
    d.add_argument("--force", action="store_true", help="download again even if the subset is present")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=_download)
    p.set_defaults(func=lambda args: (p.print_help(), 1)[1])


def _download(args: argparse.Namespace) -> int:
    from doabench.corpora.download import DEFAULT_BASE_URL, download_librispeech

    final = download_librispeech(args.subset, args.dest, base_url=args.base_url or DEFAULT_BASE_URL,
                                 keep_archive=args.keep_archive, force=args.force, progress=not args.quiet)
    print(f"LibriSpeech {args.subset} is in {final}")
    print(f"use it with --librispeech {final.parent} (or export DOABENCH_LIBRISPEECH={final.parent})")
    return 0
