"""``semslam info CLOUD``: points, valid/NaN counts, fields, encoding, organisation, viewpoint and bounds
of a point-cloud file (PCD, PLY or NPY)."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    parser = subparsers.add_parser(
        "info",
        parents=[common],
        help="describe a point-cloud file (PCD, PLY, NPY)",
        description="Print the number of points (valid and NaN), the fields (name, size, type, count), the "
        "encoding, WIDTH x HEIGHT, the viewpoint and the bounds of a point-cloud file.",
    )
    parser.add_argument("cloud", metavar="CLOUD", help="a .pcd, .ply or .npy file")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..io._info import describe_file, format_info
    from ._output import emit

    info = describe_file(args.cloud)
    emit(args, info, lambda: format_info(info))
    return 0
