"""``wholehand grasps ...``: generate and list stored grasps."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, cast

from wholehand.cli.arguments import count, natural

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from wholehand.grasps.checks import GraspCheck
    from wholehand.models.hand import HandModel
    from wholehand.models.objects import ObjectModel

REQUIRE_HOLD_HELP = (
    "keep only grasps that force regulation holds through the perturbation protocol with this "
    "rotational pull [deg], as `wholehand run --theta DEG` runs it (in the air only)"
)
REQUIRE_REACH_HELP = (
    "keep only grasps that the reacher closes within SECONDS of the start of `wholehand reach` "
    "(with --on-table: `--start table`) and keeps for 1 s, from 5 seeded starts"
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    grasps = sub.add_parser("grasps", help="generate or list stored grasps")
    gsub = grasps.add_subparsers(dest="grasps", required=True)
    p = gsub.add_parser("generate", help="generate grasps in MuJoCo (seeded)")
    p.add_argument("--hand", default="allegro_right", help="shipped hand name or hand folder")
    p.add_argument(
        "--method",
        choices=("preshape", "optimize"),
        default=None,
        help="preshape: close the style's pre-shape from random palm poses (the default where "
        "hand.toml's style has a close_torque); optimize: optimise contact points, force "
        "closure and penetration from random starts (wholehand/grasps/synthesis.py; the "
        "default for a hand without one); both validate each candidate in MuJoCo",
    )
    p.add_argument(
        "--type",
        default="power",
        help="grasp style of the hand's hand.toml: power ([grasping]) or e.g. precision "
        "([grasping.precision]); several, comma-separated (e.g. power,pinch): each in turn "
        "for what the ones before it left of --count, into its own file (with --out: "
        "DIR/<style>/ for each but power)",
    )
    p.add_argument(
        "--object",
        action="append",
        help="object name (repeatable), or 'all' for every YCB mesh; default: the paper's five",
    )
    p.add_argument(
        "--on-table",
        action="store_true",
        help="the object rests on a table and the hand comes from above; written to the "
        "style's on_table/ folder",
    )
    p.add_argument("--count", type=count, default=10, help="grasps to keep (>= 1)")
    p.add_argument("--seed", type=natural, default=0)
    p.add_argument(
        "--max-candidates", type=count, default=400, help="give up after this many (>= 1)"
    )
    p.add_argument(
        "--require-hold",
        type=float,
        default=None,
        metavar="DEG",
        help=REQUIRE_HOLD_HELP,
    )
    p.add_argument(
        "--require-reach",
        type=float,
        default=None,
        metavar="SECONDS",
        help=REQUIRE_REACH_HELP,
    )
    _hold_options(p)
    p.add_argument(
        "--envelop",
        choices=("coupled", "all", "none"),
        default="coupled",
        help="--method optimize: which fingers get a contact point on each phalanx, so that the "
        "grasp rests on their whole length: coupled (default: fingers whose phalanges one motor "
        "drives), all, or none (one contact point per finger)",
    )
    p.add_argument(
        "--out",
        default=None,
        help="folder for <object>.json; default: the hand's grasp folder (grasps/ beside a "
        "user's hand.toml, the shipped grasps for a shipped hand)",
    )
    p.set_defaults(func=_cmd_generate)
    p = gsub.add_parser(
        "import",
        help="convert grasp files of DexGraspNet, Dexonomy or BODex to this hand's format",
    )
    p.add_argument(
        "files", nargs="+", help="the .npy files (read without running anything they name)"
    )
    p.add_argument("--format", required=True, choices=("dexgraspnet", "dexonomy", "bodex"))
    p.add_argument("--hand", default="allegro_right", help="shipped hand name or hand folder")
    p.add_argument("--object", required=True, help="the object the grasps are of")
    p.add_argument(
        "--joint-names",
        default=None,
        help="the file's joint order, comma-separated, for files that do not name their joints",
    )
    p.add_argument(
        "--joint-map",
        default=None,
        help="the file's joint names onto the hand's where they differ: their=ours,...",
    )
    p.add_argument(
        "--root-offset",
        default=None,
        help="the hand's base frame in the file's hand root: 'x y z qw qx qy qz' [m] "
        "(default: the same frame)",
    )
    p.add_argument(
        "--object-scale",
        type=float,
        default=1.0,
        help="keep the grasps made on the object mesh at this scale (default 1)",
    )
    p.add_argument("--type", default="power", help="grasp style to store them as")
    p.add_argument("--out", default=None, help="folder for <object>.json (default: the hand's)")
    p.set_defaults(func=_cmd_import)
    p = gsub.add_parser(
        "check",
        help="run a hand's stored grasps of an object through --require-reach / --require-hold "
        "and say which pass; --keep-passing rewrites the file with those alone",
    )
    p.add_argument("--hand", default="allegro_right", help="shipped hand name or hand folder")
    p.add_argument("--object", required=True, help="the object whose grasp file is checked")
    p.add_argument("--type", default="power", help="grasp style of the file (default power)")
    p.add_argument("--on-table", action="store_true", help="the style's table-top grasp file")
    p.add_argument(
        "--require-hold", type=float, default=None, metavar="DEG", help=REQUIRE_HOLD_HELP
    )
    p.add_argument(
        "--require-reach", type=float, default=None, metavar="SECONDS", help=REQUIRE_REACH_HELP
    )
    _hold_options(p)
    p.add_argument(
        "--keep-passing",
        action="store_true",
        help="write the passing grasps back to the file (their ids kept), dropping the others",
    )
    p.set_defaults(func=_cmd_check)
    p = gsub.add_parser("list", help="list the shipped grasp files")
    p.set_defaults(func=_cmd_list)


def _hold_options(p: argparse.ArgumentParser) -> None:
    """``--hold-trials`` and ``--hold-rate``, the options of ``--require-hold``."""
    p.add_argument(
        "--hold-trials",
        type=count,
        default=1,
        metavar="N",
        help="--require-hold: run the protocol N times, pulling about the random axes of seeds "
        "0..N-1, and keep a grasp held in at least --hold-rate of them (default 1)",
    )
    p.add_argument(
        "--hold-rate",
        type=float,
        default=0.8,
        metavar="FRACTION",
        help="--require-hold with --hold-trials: the least share of the trials a grasp must "
        "hold (default 0.8)",
    )


def _cmd_generate(args: argparse.Namespace) -> int:
    from wholehand.grasps.generate import named_style
    from wholehand.grasps.store import grasps_dir, hand_grasps_dir
    from wholehand.models.hand import load_hand
    from wholehand.models.object_catalogue import PAPER_OBJECTS, available_objects

    hand = load_hand(args.hand)
    styles = [style.strip() for style in args.type.split(",") if style.strip()]
    methods = {}
    for style in styles:
        named_style(hand, style)  # an unknown style is named before any work
        methods[style] = args.method or default_method(hand, style)
        if args.method is None and methods[style] == "optimize":
            print(
                f"{hand.config.path} [grasping] has no close_torque for the {style} style: "
                "grasps by optimisation (--method optimize)"
            )
    shipped = hand_grasps_dir(args.hand).is_relative_to(grasps_dir())
    ycb = available_objects()
    names = args.object or list(PAPER_OBJECTS)
    if "all" in names:
        names = ycb
    without: list[str] = []
    for name in names:
        outcome = _generate_styles(args, hand, name, methods, ship=shipped and name in ycb)
        if outcome == "interrupted":
            return 130  # the objects after this one are not tried
        if outcome == "none":
            without.append(name)
    if len(names) > 1:
        kinds = " or ".join(styles)
        print(f"{len(names) - len(without)} of {len(names)} objects yield {kinds} grasps")
        if without:
            print(f"none for: {', '.join(without)}")
    return 0


def _generate_styles(
    args: argparse.Namespace, hand: HandModel, name: str, methods: dict[str, str], ship: bool
) -> str:
    """One object's grasps in each style of ``methods`` (style -> method) in turn, each asked
    for what the styles before it left of ``--count``; ``"written"`` when some style wrote
    grasps, else ``"none"``, or ``"interrupted"`` (the later styles are not tried)."""
    found, written = 0, False
    for style, method in methods.items():
        if found >= args.count:
            break
        outcome, n = _generate_for(args, hand, name, style, method, args.count - found, ship)
        if outcome == "interrupted":
            return outcome
        found += n
        written = written or outcome == "written"
    return "written" if written else "none"


def default_method(hand: HandModel, style: str) -> str:
    """``grasps generate``'s method when none is given: the pre-shape generator where the
    hand's grasp style says how to close it (a ``close_torque``), else the optimiser, which
    needs nothing from hand.toml's [grasping] tables."""
    from wholehand.grasps.generate import named_style

    return "preshape" if named_style(hand, style).close_torque else "optimize"


def _generate_for(
    args: argparse.Namespace,
    hand: HandModel,
    name: str,
    style: str,
    method: str,
    wanted: int,
    ship: bool,
) -> tuple[str, int]:
    """Generate and write up to ``wanted`` grasps of one object in ``style`` by ``method`` as
    ``args`` say otherwise, print what came of it; returns ``"written"``, ``"none"`` or
    ``"interrupted"``, and the grasps written. ``ship``: also ship the object's convex
    decomposition (a shipped hand's grasp of a YCB object, so that MuJoCo reproduces it
    without running CoACD again)."""
    from wholehand.grasps.generate import generate_grasps
    from wholehand.grasps.optimized import synthesize_grasps
    from wholehand.grasps.store import grasp_file, save_grasps
    from wholehand.grasps.synthesis_params import SynthesisParams
    from wholehand.models.convex import ship_decompositions
    from wholehand.models.object_catalogue import load_object

    obj = load_object(name)
    check = _checks(args, hand, obj, style)
    common = (hand, obj, wanted, args.seed, args.max_candidates)
    options = {"progress": True, "style": style, "on_table": args.on_table, "check": check}
    if method == "optimize":
        params = SynthesisParams(envelop=args.envelop)
        grasps, info = synthesize_grasps(*common, params=params, **options)
        if args.envelop != "coupled":
            info["command"] = f"{info['command']} --envelop {args.envelop}"
    else:
        grasps, info = generate_grasps(*common, **options)
    if args.require_hold is not None or args.require_reach is not None:
        info["command"] = f"{info['command']} {_check_options(args)}"
    rejected = cast(dict[str, int], info["rejected"])
    depths = cast(dict[str, float], info.get("preshape_depth_mm", {}))
    interrupted = bool(info.get("interrupted"))
    if not grasps:
        if interrupted:
            print(f"{obj.name}: interrupted after {info['candidates_tried']} candidates, no grasp")
            return "interrupted", 0
        print(
            f"{obj.name}: no {style} grasp from {info['candidates_tried']} candidates; "
            "nothing written (raise --max-candidates or adjust the style in hand.toml). "
            f"Rejected because:\n{_reasons(rejected, depths)}"
        )
        return "none", 0
    default = grasp_file(args.hand, obj.name, style, args.on_table)
    several = "," in args.type
    kind = f"{style} " if several else ""
    path = default
    if args.out:  # several styles: each but power in its own subfolder, as in a hand's folder
        path = Path(args.out) / (style if several and style != "power" else "") / default.name
    path = save_grasps(path, hand.name, obj.name, grasps, info)
    if args.verbose and rejected:
        print(f"{obj.name}: candidates rejected because:\n{_reasons(rejected, depths)}")
    if not args.out and ship:
        ship_decompositions([obj.name])
    print(
        f"{obj.name}: {len(grasps)} {kind}grasps from {info['candidates_tried']} candidates"
        f"{_how_it_ended(args, wanted, len(grasps), info)} -> {path}"
    )
    return "interrupted" if interrupted else "written", len(grasps)


def _checks(
    args: argparse.Namespace, hand: HandModel, obj: ObjectModel, style: str
) -> GraspCheck | None:
    """The further checks ``--require-hold`` and ``--require-reach`` ask for, as one, for
    grasps of ``style``.

    Raises:
        ConfigError: ``--require-hold`` with ``--on-table``; ``--hold-rate`` outside (0, 1].
    """
    from wholehand.errors import ConfigError
    from wholehand.grasps.checks import all_of
    from wholehand.reaching.reach_check import reach_check
    from wholehand.trials.hold_check import protocol_check

    if args.require_hold is not None and args.on_table:
        raise ConfigError(
            "--require-hold runs the perturbation protocol in the air; it cannot check table-top "
            "grasps (leave out --on-table or --require-hold)"
        )
    checks: list[GraspCheck] = []
    if not 0.0 < args.hold_rate <= 1.0:
        raise ConfigError(f"--hold-rate {args.hold_rate:g}: give a share in (0, 1], e.g. 0.8")
    if args.require_hold is not None:
        checks.append(
            protocol_check(
                hand, obj, args.require_hold, trials=args.hold_trials, min_rate=args.hold_rate
            )
        )
    if args.require_reach is not None:
        checks.append(reach_check(hand, obj, style, args.require_reach, args.on_table))
    return all_of(checks)


def _how_it_ended(
    args: argparse.Namespace, wanted: int, found: int, info: dict[str, object]
) -> str:
    """The summary line's note: interrupted, or short of the ``wanted`` grasps, and the faces
    covered."""
    note = ""
    if info.get("interrupted"):
        note = " (interrupted: the grasps found so far are written)"
    elif found < wanted:
        asked = f"--count {args.count}" if wanted == args.count else f"the {wanted} still wanted"
        note = (
            f" (fewer than {asked}: the limit of --max-candidates "
            f"{args.max_candidates} was reached)"
        )
    faces = cast(list[int], info.get("grasps_per_face", []))
    if faces:
        note += (
            f" on {sum(n > 0 for n in faces)} of its {len(faces)} resting faces "
            f"(grasps per face, likeliest first: {faces})"
        )
    return note


def _import_options(
    args: argparse.Namespace,
) -> tuple[dict[str, str], npt.NDArray[np.float64] | None, list[str] | None]:
    """``grasps import``'s joint map, root offset (4, 4) and joint names, checked."""
    from wholehand.errors import ConfigError
    from wholehand.grasps.importers import pose_matrix, pose_problem

    joint_map = {}
    for pair in filter(None, (args.joint_map or "").split(",")):
        theirs, sep, ours = pair.partition("=")
        if not sep or not theirs.strip() or not ours.strip():
            raise ConfigError(f"--joint-map: {pair!r} is not their=ours")
        joint_map[theirs.strip()] = ours.strip()
    offset = None
    if args.root_offset:
        try:
            values = [float(v) for v in args.root_offset.split()]
        except ValueError:
            values = []
        if len(values) != 7:
            raise ConfigError(
                f"--root-offset: {args.root_offset!r} is not seven numbers 'x y z qw qx qy qz'"
            )
        problem = pose_problem(values, "pose")
        if problem:
            raise ConfigError(f"--root-offset: {args.root_offset!r} is not a pose: {problem}")
        offset = pose_matrix(values)
    names = [n.strip() for n in (args.joint_names or "").split(",") if n.strip()] or None
    return joint_map, offset, names


def _cmd_import(args: argparse.Namespace) -> int:
    from wholehand.errors import ConfigError
    from wholehand.grasps.importers import import_grasps
    from wholehand.grasps.store import grasp_file, object_key, save_grasps
    from wholehand.models.hand import load_hand
    from wholehand.models.object_catalogue import load_object

    if not (args.object_scale > 0 and args.object_scale < float("inf")):
        raise ConfigError(
            f"--object-scale {args.object_scale}: give the mesh scale the grasps were made at, "
            "a positive number (default 1)"
        )
    load_object(args.object)  # an object that does not exist is named before any file is read
    hand = load_hand(args.hand)
    joint_map, offset, names = _import_options(args)
    grasps, record = import_grasps(
        hand,
        args.files,
        args.format,
        joint_names=names,
        joint_map=joint_map,
        root_offset=offset,
        object_scale=args.object_scale,
        grasp_type=args.type,
    )
    skipped = cast(dict[str, int], record["skipped"])
    if not grasps:
        print(f"no grasp of the {record['read']} read was usable; skipped:\n{_reasons(skipped)}")
        return 1
    default = grasp_file(args.hand, args.object, args.type)
    path = Path(args.out) / default.name if args.out else default
    path = save_grasps(path, hand.name, object_key(args.object), grasps, record)
    print(f"{len(grasps)} of {record['read']} grasps -> {path}")
    if skipped:
        print(f"skipped:\n{_reasons(skipped)}")
    if record["ignored_joints"]:
        print(f"joints of the files that {hand.name} does not have: {record['ignored_joints']}")
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    import json

    from wholehand.errors import ConfigError
    from wholehand.grasps.store import grasp_file, load_grasps, save_grasps
    from wholehand.models.hand import load_hand
    from wholehand.models.object_catalogue import load_object

    if args.require_hold is None and args.require_reach is None:
        raise ConfigError("grasps check: give --require-reach SECONDS, --require-hold DEG or both")
    hand, obj = load_hand(args.hand), load_object(args.object)
    path = grasp_file(args.hand, obj.name, args.type, args.on_table)
    grasps = load_grasps(path)
    check = _checks(args, hand, obj, args.type)
    assert check is not None
    verdicts: dict[int, str | None] = {}
    for grasp in grasps:  # each as it is checked: a reach takes seconds
        verdicts[grasp.id] = check(grasp)
        print(f"grasp {grasp.id}: {verdicts[grasp.id] or 'passes'}", flush=True)
    passing = [grasp for grasp in grasps if verdicts[grasp.id] is None]
    print(f"{len(passing)} of {len(grasps)} grasps pass")
    if not args.keep_passing or len(passing) == len(grasps):
        return 0
    if not passing:
        print(f"none pass: {path} is left as it is")
        return 1
    info = json.loads(path.read_text()).get("generator", {})
    kept = [g.id for g in passing]
    info["checked"] = f"{_check_options(args)}: kept grasps {kept} of {len(grasps)}"
    save_grasps(path, hand.name, obj.name, passing, info)
    print(f"kept {len(passing)} -> {path}")
    return 0


def _check_options(args: argparse.Namespace) -> str:
    """The command-line options of the checks ``args`` ask for."""
    options = []
    if args.require_hold is not None:
        options.append(f"--require-hold {args.require_hold:g}")
        if args.hold_trials > 1:
            options.append(f"--hold-trials {args.hold_trials} --hold-rate {args.hold_rate:g}")
    if args.require_reach is not None:
        options.append(f"--require-reach {args.require_reach:g}")
    return " ".join(options)


def _reasons(rejected: dict[str, int], depths: dict[str, float] | None = None) -> str:
    lines = [f"  {n:4d}  {reason}" for reason, n in rejected.items()]
    if depths:
        deepest = ", ".join(f"{link} {mm:g} mm" for link, mm in depths.items())
        lines.append(f"  the pre-shape's deepest penetration per link: {deepest}")
    return "\n".join(lines)


def _cmd_list(args: argparse.Namespace) -> int:
    from wholehand.grasps.store import grasps_dir, load_grasps, shipped_grasp_files

    for path in shipped_grasp_files():
        grasps = load_grasps(path)
        styles = sorted({g.type for g in grasps})
        name = path.relative_to(grasps_dir()).with_suffix("").as_posix()
        print(f"{name}: {len(grasps)} grasps ({', '.join(styles)})")
    return 0
