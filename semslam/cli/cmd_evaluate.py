"""``semslam evaluate DB_OR_VIEWS_DIR``: leave-one-out recognition accuracy of a view database.

Prints the confusion matrix (rows actual, columns predicted), the accuracy and the per-class recall, as
Tables 1-2 of Himri et al. (2018). A views folder (``CLASS/VIEW.pcd``) is turned into a database first.
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    parser = subparsers.add_parser(
        "evaluate", parents=[common], help="leave-one-out recognition accuracy of a view database",
        description="Classify every view of a database with a classifier trained on the others and print the "
                    "confusion matrix (rows actual, columns predicted), accuracy and per-class recall.")
    parser.add_argument("source", metavar="DB_OR_VIEWS_DIR", help="database file (.npz) or views folder CLASS/VIEW.pcd")
    parser.add_argument("--descriptor", choices=("esf", "vfh", "esf+vfh"), default="esf", help="default esf")
    parser.add_argument("--classifier", choices=("chi2", "svm"), default="chi2",
                        help="chi-square nearest view, or RBF SVM with Hsu et al.'s grid search (default chi2)")
    parser.add_argument("--seed", type=int, default=0, help="seed (SVM folds; ESF when building from a folder)")
    parser.add_argument(
        "--jobs",
        type=int,
        default=-1,
        help="processes fitting the SVM folds (default -1: every core; the result does not depend on it)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..recognition import build_database_from_folder, load_database
    from ..evaluation.classifier import leave_one_out
    from ._output import emit

    source = Path(args.source)
    # a folder of views in any unit or from any sensor: grid and normal radius from their measured point spacing
    db = (build_database_from_folder(source, seed=args.seed, normal_radius_m="auto", voxel_leaf_m="auto")
          if source.is_dir() else load_database(source))
    result = leave_one_out(db, descriptor=args.descriptor, classifier=args.classifier, seed=args.seed,
                           n_jobs=args.jobs)
    emit(args, {"source": str(source), **result.to_dict()}, result.format_table)
    return 0
