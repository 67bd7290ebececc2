"""``fruitnerfpp segment``: compute instance masks for a transforms.json dataset that has none.

Example::

    fruitnerfpp segment DATA_DIR                                   # built-in fallback segmenter
    fruitnerfpp segment DATA_DIR --method torchscript --checkpoint fruit_instances.pt
    fruitnerfpp segment DATA_DIR --method sam --checkpoint sam_vit_b_01ec64.pth --device cuda
    fruitnerfpp segment DATA_DIR --config config/segmentation.yaml --overwrite
    fruitnerfpp segment DATA_DIR --method semantic                 # from the dataset's own binary fruit masks

Writes ``instances/*.png`` (16-bit ids) and ``semantics/*.png`` and records them in transforms.json. Torch is
imported only by the model methods (``fruitnerfpp --help`` stays fast).
"""

from __future__ import annotations

import argparse
from typing import Any

from fruitnerfpp_ros.core.progress import ProgressEvent

__all__ = ['register', 'run']


def register(subparsers: Any) -> None:
    """Add the ``segment`` subcommand."""
    parser = subparsers.add_parser(
        'segment', help='compute fruit instance masks for a dataset (fallback, TorchScript model or SAM)',
        description='Segment every image of a transforms.json dataset into fruit instances; write instances/*.png '
                    '(16-bit ids) and semantics/*.png and record them in transforms.json.')
    parser.add_argument('dataset', metavar='DATA_DIR', help='dataset directory holding transforms.json')
    parser.add_argument('--method', choices=('fallback', 'torchscript', 'sam', 'semantic'),
                        help='fallback (built-in colour segmenter, default), torchscript (local TorchScript model), '
                             "sam (Segment Anything, local checkpoint) or semantic (the dataset's own fruit masks, "
                             'semantic_path, split into instances at the necks between touching fruits)')
    parser.add_argument('--checkpoint', metavar='PATH', help='local model file for torchscript / sam')
    parser.add_argument('--device', help='auto (default), cpu or cuda[:N] for torchscript / sam')
    parser.add_argument('--config', metavar='FILE.yaml',
                        help='YAML with SegmenterConfig values (e.g. config/segmentation.yaml); flags override it')
    parser.add_argument('--overwrite', action='store_true', help='replace masks the dataset already has')
    parser.add_argument('--quiet', action='store_true', help='no progress bar')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``segment`` from parsed arguments; returns the exit code."""
    from fruitnerfpp_ros.core.segmentation import SegmenterConfig, build_segmenter
    from fruitnerfpp_ros.core.segmentation.dataset_masks import check_no_masks, segment_dataset

    semantic = args.method == 'semantic'
    config = SegmenterConfig.load(args.config, **({} if semantic else dict(
        method=args.method, checkpoint=args.checkpoint, device=args.device)))
    if not args.overwrite and not semantic:
        check_no_masks(args.dataset)  # before a model is loaded
    segmenter = None if semantic else build_segmenter(config)

    bar: Any = None

    def on_progress(event: ProgressEvent) -> None:
        nonlocal bar
        if args.quiet:
            return
        if bar is None:
            from tqdm import tqdm
            bar = tqdm(total=event.total, desc=f'segment ({args.method or config.method})', unit='image')
        bar.n = event.step
        bar.set_postfix_str(event.message, refresh=False)
        bar.refresh()

    try:
        if semantic:
            from fruitnerfpp_ros.core.segmentation.semantic_instances import instances_from_semantics
            summary = instances_from_semantics(args.dataset, config, overwrite=args.overwrite, progress=on_progress)
        else:
            summary = segment_dataset(args.dataset, segmenter, overwrite=args.overwrite, progress=on_progress)
    finally:
        if bar is not None:
            bar.close()
    print(f'segmented {summary.n_frames} images of {summary.dataset_dir} with {args.method or config.method}: '
          f'{summary.n_instances} instances ({summary.n_instances / max(summary.n_frames, 1):.1f} per image, '
          f'{summary.empty_frames} images without fruit) in {summary.seconds:.1f} s')
    return 0
