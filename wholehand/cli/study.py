"""``wholehand study NAME``: one of the paper's simulation studies, in a process pool."""

from __future__ import annotations

import argparse
import json


def add_parser(sub: argparse._SubParsersAction) -> None:
    from wholehand.studies import SIZES, STUDIES
    from wholehand.studies.base import DEFAULT_HAND

    p = sub.add_parser(
        "study",
        help="run one of the paper's simulation studies (trials.csv, summary.json, PNG)",
        description="Expands a study into seeded trials, runs them in a process pool with a "
        "progress bar and writes trials.csv, summary.json and a plot to --out. Every finished "
        "trial is appended at once to --out/rows.jsonl, so a run that is stopped (Ctrl-C, "
        "--limit) can be continued with --resume, on this machine or another. Studies: "
        + "; ".join(f"{name}: {cls.description}" for name, cls in STUDIES.items()),
    )
    p.add_argument("name", choices=sorted(STUDIES), help="which study")
    p.add_argument("--quick", action="store_true", help="the < 2 min subset (same as --size quick)")
    p.add_argument("--size", choices=SIZES, default=None, help="tiny, quick or full (default full)")
    p.add_argument("--out", default=None, help="output folder (default out/study-<name>)")
    p.add_argument("--workers", type=int, default=None, help="pool size (default: CPU count)")
    p.add_argument(
        "--executor",
        choices=("process", "serial", "ray"),
        default="process",
        help="process pool (default), serial, or Ray (pip install 'wholehand[ray]')",
    )
    p.add_argument(
        "--address",
        default=None,
        help="--executor ray: cluster address (e.g. auto, ray://head:10001); default: local Ray",
    )
    p.add_argument("--seed", type=int, default=0, help="study seed (random pull axes)")
    p.add_argument(
        "--hand",
        default=DEFAULT_HAND,
        help="shipped hand name or hand folder (its stored grasps of the design are run)",
    )
    p.add_argument(
        "--methods",
        default=None,
        metavar="A,B,...",
        help="allocators to compare instead of the study's own (any registered allocator, "
        "third-party plug-ins included; see `wholehand plugins`)",
    )
    p.add_argument(
        "--grasps",
        default=None,
        metavar="DIR",
        help="run the grasps in DIR/<object>.json (e.g. from `wholehand grasps generate --out "
        "DIR`) instead of the hand's stored ones; trials past a file's grasps are dropped",
    )
    p.add_argument(
        "--only",
        action="append",
        default=None,
        metavar="COLUMN=VALUE",
        help="run only the trials whose column (a label such as method or a spec field such "
        "as theta_deg or object) has this value; repeat it: one of the values of a column, "
        "every column (e.g. --only theta_deg=90 --only method=qp)",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue the run in --out: reuse the finished trials of its rows.jsonl and "
        "trials.csv (matched by content: labels and spec, seed included; trials that raised "
        "run again) and run only the others (default: start afresh, replacing rows.jsonl)",
    )
    p.add_argument(
        "--limit",
        type=int,
        default=None,
        metavar="N",
        help="run at most N unfinished trials this time, then write partial outputs "
        '("complete": false); with --resume, a long study runs in chunks over sessions',
    )
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.add_argument(
        "--view",
        type=int,
        default=None,
        metavar="INDEX",
        help="instead of the study, run its trial INDEX alone, live in meshcat (prints the URL)",
    )
    p.add_argument("--view-every", type=int, default=8, help="--view: draw every n-th cycle")
    p.set_defaults(func=_cmd_study)


def _cmd_study(args: argparse.Namespace) -> int:
    from wholehand.errors import ConfigError
    from wholehand.studies import get_study, run_study

    if args.quick and args.size not in (None, "quick"):
        raise ConfigError(f"--quick contradicts --size {args.size}; pass one of them")
    size = "quick" if args.quick else (args.size or "full")
    if args.view is not None:
        return _view_one(args, size)
    result = run_study(
        get_study(args.name),
        size=size,
        out=args.out,
        workers=args.workers,
        executor=args.executor,
        address=args.address,
        seed=args.seed,
        progress=not args.no_progress,
        resume=args.resume,
        limit=args.limit,
        hand=args.hand,
        methods=_methods(args),
        grasps=args.grasps,
        only=_only(args),
    )
    summary = {k: v for k, v in result.summary.items() if k != "description"}
    print(json.dumps(summary, indent=2))
    print(
        f"wrote {result.csv_path}, {result.summary_path}, {result.plot_path} "
        f"(journal {result.journal_path})"
    )
    return 130 if result.interrupted else 0


def _methods(args: argparse.Namespace) -> tuple[str, ...] | None:
    if args.methods is None:
        return None
    return tuple(m.strip() for m in args.methods.split(",") if m.strip())


def _only(args: argparse.Namespace) -> dict[str, tuple[str, ...]] | None:
    from wholehand.errors import ConfigError

    if not args.only:
        return None
    out: dict[str, tuple[str, ...]] = {}
    for item in args.only:
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise ConfigError(f"--only {item!r}: write COLUMN=VALUE, e.g. --only theta_deg=90")
        out[key.strip()] = (*out.get(key.strip(), ()), value.strip())
    return out


def _view_one(args: argparse.Namespace, size: str) -> int:
    """Run one trial of the study in this process with the live viewer."""
    from wholehand.cli.run import live_view, print_summary, summarise
    from wholehand.errors import ConfigError
    from wholehand.studies import get_study
    from wholehand.studies.runner import study_jobs
    from wholehand.trials.trial import run_trial

    study = get_study(args.name)
    jobs = study_jobs(study, size, args.seed, args.hand, _methods(args), args.grasps, _only(args))
    jobs = [j for j in jobs if j.kind == "trial"]
    if not 0 <= args.view < len(jobs):
        raise ConfigError(
            f"--view {args.view}: study {args.name} ({size}) has trials 0..{len(jobs) - 1}"
        )
    job = jobs[args.view]
    print(f"trial {job.index}: {job.labels}")
    record = run_trial(job.spec, observers=[live_view(job.spec, args.view_every)])
    print_summary(summarise(record))
    return 0
