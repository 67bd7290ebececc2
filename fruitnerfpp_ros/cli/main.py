"""Entry point of the ``fruitnerfpp`` command.

Each subcommand lives in its own module exposing ``register(subparsers)``, which adds its parser and sets
``func`` (a callable taking the parsed namespace and returning an exit code). Errors derived from
:class:`FruitNerfError` are printed as one line, never as a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from fruitnerfpp_ros import __version__
from fruitnerfpp_ros.errors import FruitNerfError

__all__ = ['main', 'build_parser']

#: Modules under ``fruitnerfpp_ros.cli`` that register subcommands, in help order.
SUBCOMMAND_MODULES = ('synth', 'segment', 'train', 'results', 'track', 'replay', 'orchard', 'demo', 'bench')


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='fruitnerfpp', description='FruitNeRF++ fruit counting.')
    parser.add_argument('--version', action='version', version=f'%(prog)s {__version__}')
    subparsers = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name in SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(f'fruitnerfpp_ros.cli.{name}')
        except ModuleNotFoundError as err:
            if err.name != f'fruitnerfpp_ros.cli.{name}':
                raise
            continue
        module.register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except FruitNerfError as err:
        print(f'fruitnerfpp {args.command}: error: {err}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'fruitnerfpp {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
