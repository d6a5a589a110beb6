"""The ``wholehand`` command: run, study, bench, plugins, info."""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from collections.abc import Callable

from wholehand.errors import WholehandError


def _cmd_plugins(args: argparse.Namespace) -> int:
    from wholehand import registry

    for group, entry_group in registry.GROUPS.items():
        print(f"{entry_group}:")
        specs = registry.available(group)
        if not specs:
            print("  (none installed)")
        for name, spec in specs.items():
            origin = "" if spec.builtin else f"  [{spec.distribution}]"
            print(f"  {name:<20} {spec.description()}{origin}")
    return 0


def _cmd_info(args: argparse.Namespace) -> int:
    from wholehand.models.hand import load_hand
    from wholehand.models.object_catalogue import load_object

    hand = load_hand(args.hand)
    obj = load_object(args.object)
    report = {"hand": hand.summary(), "object": obj.summary()}
    if not args.verbose:
        report["hand"].pop("points_per_link")
    print(json.dumps(report, indent=2))
    return 0


def _cmd_hands(args: argparse.Namespace) -> int:
    from wholehand.models.hand_folders import available_hands

    print("\n".join(available_hands()))
    return 0


def _cmd_objects(args: argparse.Namespace) -> int:
    from wholehand.models.object_catalogue import available_objects

    print("\n".join(available_objects()))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="wholehand",
        description="Real-time force regulation of whole-hand dexterous grasps.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("plugins", help="list installed plug-ins by group")
    p.set_defaults(func=_cmd_plugins)

    p = sub.add_parser("hands", help="list the shipped hands")
    p.set_defaults(func=_cmd_hands)

    p = sub.add_parser("objects", help="list the loadable objects")
    p.set_defaults(func=_cmd_objects)

    p = sub.add_parser("info", help="load a hand and an object and print their summary (JSON)")
    p.add_argument("--hand", default="allegro_right", help="shipped hand name or hand folder")
    p.add_argument("--object", default="077_rubiks_cube", help="YCB name, primitive or mesh path")
    p.set_defaults(func=_cmd_info)

    from wholehand.cli import bench as bench_cli
    from wholehand.cli import grasps as grasps_cli
    from wholehand.cli import hand as hand_cli
    from wholehand.cli import hardware as hardware_cli
    from wholehand.cli import reach as reach_cli
    from wholehand.cli import run as run_cli
    from wholehand.cli import study as study_cli
    from wholehand.cli import view as view_cli

    run_cli.add_parser(sub)
    reach_cli.add_parser(sub)
    study_cli.add_parser(sub)
    grasps_cli.add_parser(sub)
    hand_cli.add_parser(sub)
    bench_cli.add_parser(sub)
    view_cli.add_parser(sub)
    hardware_cli.add_parser(sub)
    _verbose_everywhere(parser)
    return parser


def _verbose_everywhere(parser: argparse.ArgumentParser) -> None:
    """Accept ``-v`` after any subcommand too (``wholehand info -v`` as well as
    ``wholehand -v info``); SUPPRESS keeps a subcommand from resetting the top-level flag."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for subparser in action.choices.values():
                subparser.add_argument(
                    "-v",
                    "--verbose",
                    action="store_true",
                    default=argparse.SUPPRESS,
                    help="log progress details",
                )
                _verbose_everywhere(subparser)


def _refuse_empty(
    parser: argparse.ArgumentParser, args: argparse.Namespace, argv: list[str]
) -> None:
    """An argument given an empty value (``--object ''``) is an error, never its default."""
    for dest, value in vars(args).items():
        values = value if isinstance(value, list) else [value]
        if any(isinstance(v, str) and not v.strip() for v in values):
            option = f"--{dest.replace('_', '-')}"
            name = option if option in argv else dest
            parser.error(f"{name} is empty; give a value or leave it out")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    _refuse_empty(parser, args, sys.argv[1:] if argv is None else argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(message)s"
    )
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except WholehandError as err:
        print(f"wholehand: error: {err}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the reader left (`wholehand objects | head`): stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # Python's exit flush must not fail again
        return 0


if __name__ == "__main__":
    sys.exit(main())
