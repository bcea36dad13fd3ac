"""``fastdet mine SOURCE... --annotations A.json --out DIR``: hard negatives."""

from __future__ import annotations

from .common import add_annotation_options, add_model_options, annotated_sources, make_detector


def add_mine_parser(subparsers):
    """Register ``mine`` on the ``fastdet`` command's sub-parsers."""
    mine = subparsers.add_parser("mine",
                                 help="save false hits on annotated frames as negative crops")
    mine.add_argument("sources", nargs="+", metavar="SOURCE", help="images and/or videos")
    add_annotation_options(mine, "mine")
    mine.add_argument("--out", required=True, metavar="DIR", help="folder for the 64x64 crops")
    mine.add_argument("--max-iou", type=float, default=0.1,
                      help="a hit overlapping every vehicle less than this is a negative "
                           "(default %(default)s)")
    add_model_options(mine)
    mine.set_defaults(handler=cmd_mine)
    return mine


def cmd_mine(args):
    """Save the detector's false hits as 64x64 crops."""
    from ..errors import InputError
    from ..training.mine import check_sources, mine

    # IoU is in [0, 1] and a hit is a negative below --max-iou: 0 keeps none.  NaN fails too.
    if not 0 < args.max_iou <= 1:
        raise InputError(f"--max-iou must be in (0, 1], got {args.max_iou}")
    check_sources(args.sources)
    sources = annotated_sources(args.sources, args.annotations, args.split)
    detector = make_detector(args)
    result = mine(detector, sources, None, args.out, max_iou=args.max_iou)
    print(f"{len(result.saved)} hard negatives from {result.hits} hits in {result.frames} "
          f"annotated frames written to {args.out}")
    return 0
