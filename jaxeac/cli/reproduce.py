"""`jaxeac reproduce`: both of the paper's experiments at scale, with a verdict."""

from __future__ import annotations

import argparse

from jaxeac.cli.flags import folder_name, prng_key


def add_parser(sub) -> None:
    r = sub.add_parser("reproduce", help="re-run both of the paper's experiments at scale, with a verdict")
    r.add_argument("--quick", action="store_true", help="fewer seeds: a few minutes on a laptop CPU")
    r.add_argument("--out", type=folder_name, default="runs/reproduce", metavar="DIR",
                   help="reproduction folder (default runs/reproduce)")
    r.add_argument("--key", type=prng_key, default=0, metavar="K", help="root PRNG key, 0..2^32-1 (SPEC R1)")
    r.add_argument("--quiet", action="store_true", help="no progress bars")


def cmd_reproduce(args: argparse.Namespace) -> int:
    from jaxeac.cli.process import _claim_out
    from jaxeac.experiments.reproduce import reproduce

    _claim_out(args, args.out, kind="reproduce")
    report = reproduce(args.out, quick=args.quick, key=args.key, progress=not args.quiet)
    print(f"report in {report}")
    return 0
