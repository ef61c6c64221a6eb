"""``uav-landing score``: errors of estimated poses against a simulated sequence's ground truth."""

from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("score", help="score estimated poses (CSV or bag) against a sequence's ground truth")
    p.add_argument("--truth", type=Path, required=True, help="simulated bag directory (or its PNG + CSV folder)")
    p.add_argument("--estimate", type=Path, required=True,
                   help="CSV (stamp_ns,x,y,z,qx,qy,qz,qw[,ms]) or bag with a pose topic")
    p.add_argument("--topic", default="", help="pose topic in an estimate bag (default: /uav/pose)")
    p.add_argument("--name", default="estimate", help="variant name in the tables and JSON (e.g. C4N2)")
    p.add_argument("--json", type=Path, required=True, help="JSON summary to write")
    p.add_argument("--report-dir", type=Path, help="also write tables (txt, CSV) and error plots (PNG) here")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from .report import (
        format_table,
        frames_scored,
        make_summary,
        save_summary,
        statistics_table,
        variant_summary,
        write_report,
    )
    from ..cli import check_output
    from .score import score_files
    from .statistics import ROTATION_COLUMNS, TRANSLATION_COLUMNS

    for path, what in ((args.truth, "--truth"), (args.estimate, "--estimate")):
        if not path.exists():
            raise SystemExit(f"uav-landing score: {what} {path} does not exist")
    try:
        check_output("--json", args.json, others=(("--truth", args.truth), ("--estimate", args.estimate)))
        if args.report_dir:
            check_output("--report-dir", args.report_dir, folder=True)
        errors, ms = score_files(args.truth, args.estimate, args.topic)
    except ValueError as exc:
        raise SystemExit(f"uav-landing score: {exc}") from exc
    sequence = args.truth.resolve().name
    doc = make_summary(sequence, len(errors["euclidean"]), {args.name: variant_summary(errors, ms)})
    args.json.parent.mkdir(parents=True, exist_ok=True)
    save_summary(args.json, doc)  # first: a report whose figure fails loses no figure of the summary
    if args.report_dir:
        print(write_report(args.report_dir, sequence, {args.name: errors}))
    else:
        for kind, columns, unit in (("translation", TRANSLATION_COLUMNS, "m"), ("rotation", ROTATION_COLUMNS, "deg")):
            print(format_table(statistics_table({args.name: errors}, columns), f"{sequence}: {kind} error ({unit})"))
        print(frames_scored({args.name: errors}))  # the tables leave the lost frames out: say how many
    print(f"wrote {args.json}")
    return 0
