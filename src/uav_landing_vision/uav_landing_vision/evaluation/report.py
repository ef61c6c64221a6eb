"""Thesis-format reports: text tables, CSV tables, error-vs-frame plots, the JSON summary.

JSON summary schema (every evaluation command writes it)::

    {"sequence": str, "frames": int,
     "variants": {"C4N2": {"translation_m": {p5, p25, median, p75, p95, outlier_pct, mae, rmse, sd},
                           "rotation_deg": {same keys},
                           "lost_frames_pct": float, "ms_per_frame": float or null}}}

``translation_m`` is the Euclidean error, ``rotation_deg`` the geodesic error (3.3). A statistic
that is undefined (the SD of one frame; all of them for a variant without any estimate) is NaN
in memory and ``null`` in the file, which strict JSON readers take.
"""

import csv
import json
from pathlib import Path

import numpy as np

from .consistency import DEPTH_BINS_M, depth_bin_label, depth_bins
from .statistics import ROTATION_COLUMNS, ROW_NAMES, STAT_KEYS, TRANSLATION_COLUMNS, error_statistics

AXIS_LABELS = {"euclidean": "Euclidean", "x": "X", "y": "Y", "z": "Z",
               "geodesic": "Geodesic", "alpha": "α", "beta": "β", "gamma": "γ"}
PLOT_LIMIT = 1e6  # errors (m or deg) beyond it are left out of the plots, not the tables


class SummaryError(ValueError):
    """A JSON summary that does not follow the schema."""


def statistics_table(errors_by_variant: dict[str, dict[str, np.ndarray]], columns) -> dict[str, dict]:
    """``{"<variant> <axis>": stats}`` for every variant and every axis in ``columns``."""
    return {f"{v} {AXIS_LABELS[c]}" if len(columns) > 1 else v: error_statistics(err[c])
            for v, err in errors_by_variant.items() for c in columns}


def format_table(stats_by_column: dict[str, dict], title: str, digits: int = 2) -> str:
    """A text table with the thesis's rows and one column per entry."""
    names = list(stats_by_column)
    width = max([12] + [len(n) + 2 for n in names])
    lines = [title, f"{'':<16}" + "".join(f"{n:>{width}}" for n in names)]
    for key in STAT_KEYS:
        cells = "".join(f"{stats_by_column[n][key]:>{width}.{digits}f}" for n in names)
        lines.append(f"{ROW_NAMES[key]:<16}{cells}")
    return "\n".join(lines)


def lost_frames(errors: dict[str, np.ndarray]) -> np.ndarray:
    """The frames without an estimate (no translation or no rotation error), as a mask."""
    return ~np.isfinite(errors["euclidean"]) | ~np.isfinite(errors["geodesic"])


def lost_frames_pct(errors: dict[str, np.ndarray]) -> float:
    lost = lost_frames(errors)
    return float(100.0 * lost.mean()) if lost.size else 0.0


def frames_scored(errors_by_variant: dict[str, dict[str, np.ndarray]]) -> str:
    """How many frames each variant's statistics cover: the tables leave out the lost ones."""
    lines = []
    for v, err in errors_by_variant.items():
        lost = lost_frames(err)
        lines.append(f"{v}: statistics over {int((~lost).sum())} of {lost.size} frames "
                     f"({lost_frames_pct(err):.1f} % lost)")
    return "\n".join(lines)


def format_errors_by_depth(errors_by_variant: dict[str, dict[str, np.ndarray]], depth, title: str,
                           bins=DEPTH_BINS_M) -> str:
    """Ours (the thesis pools the whole approach): per bin of true ``depth`` (edges in m) and for
    all frames, each variant's median Euclidean translation (m) and geodesic rotation (deg)
    errors over the frames it has an estimate for, and how many those are."""
    names = list(errors_by_variant)
    width = max(24, *(len(n) + 2 for n in names))
    lines = [f"{title}: median error by true depth (translation m | rotation deg, frames)",
             f"{'true depth':<16}" + "".join(f"{n:>{width}}" for n in names)]
    errors = [(np.asarray(e["euclidean"], float), np.asarray(e["geodesic"], float)) for e in errors_by_variant.values()]
    for depth_m, in_bin in depth_bins(depth, bins):
        cells = []
        for trans, rot in errors:
            sel = in_bin & np.isfinite(trans) & np.isfinite(rot)
            cells.append(f"{np.median(trans[sel]):.2f} | {np.median(rot[sel]):.2f} ({sel.sum()})" if sel.any() else "- (0)")
        lines.append(f"{depth_bin_label(depth_m):<16}" + "".join(f"{c:>{width}}" for c in cells))
    return "\n".join(lines)


def write_table_csv(path, stats_by_column: dict[str, dict]) -> None:
    """The table as CSV: a header row of columns, one row per statistic."""
    with Path(path).open("w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["statistic", *stats_by_column])
        for key in STAT_KEYS:
            out.writerow([ROW_NAMES[key], *(repr(stats_by_column[n][key]) for n in stats_by_column)])


def plot_text(text: str) -> str:
    """``text`` drawn as written: matplotlib reads a span between two ``$`` as TeX (an unknown
    command in a user's name, a variant or a bag, made the figure and the report fail) and
    leaves a legend label that starts with ``_`` out (a zero-width space keeps it in)."""
    text = str(text).replace("$", r"\$")
    return "\u200b" + text if text.startswith("_") else text


def plot_errors(path, errors_by_variant: dict[str, dict[str, np.ndarray]], columns, unit: str) -> None:
    """Error vs. frame, one panel per axis, one line per variant (thesis Figs. 6.24–6.25)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(columns), figsize=(4.2 * len(columns), 3.2), squeeze=False)
    for ax, col in zip(axes[0], columns):
        off_chart = 0
        for name, err in errors_by_variant.items():
            beyond = np.abs(err[col]) > PLOT_LIMIT  # matplotlib cannot lay out axes out to ~1e308
            off_chart += int(beyond.sum())
            ax.plot(np.arange(len(err[col])), np.where(beyond, np.nan, err[col]), lw=0.9, label=plot_text(name))
        ax.set_title(AXIS_LABELS[col] + (f" ({off_chart} beyond ±{PLOT_LIMIT:g} not drawn)" if off_chart else ""))
        ax.set_xlabel("frame")
        ax.set_ylabel(f"error [{unit}]")
        ax.grid(True, alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def variant_summary(errors: dict[str, np.ndarray], ms_per_frame: float | None = None) -> dict:
    """One variant's entry of the JSON summary."""
    return {
        "translation_m": error_statistics(errors["euclidean"]),
        "rotation_deg": error_statistics(errors["geodesic"]),
        "lost_frames_pct": lost_frames_pct(errors),
        "ms_per_frame": None if ms_per_frame is None else float(ms_per_frame),
    }


def make_summary(sequence: str, frames: int, variants: dict[str, dict]) -> dict:
    """The JSON summary document (validated)."""
    doc = {"sequence": str(sequence), "frames": int(frames), "variants": variants}
    validate_summary(doc)
    return doc


def validate_summary(doc) -> None:
    """Raise :class:`SummaryError` unless ``doc`` follows the schema above."""
    def need(cond, msg):
        if not cond:
            raise SummaryError(msg)

    need(isinstance(doc, dict) and set(doc) == {"sequence", "frames", "variants"},
         "summary needs exactly the keys sequence, frames, variants")
    frames = doc["frames"]
    need(isinstance(doc["sequence"], str) and type(frames) is int and frames >= 0,
         f"sequence: str, frames: a non-negative int (got {frames!r})")
    need(isinstance(doc["variants"], dict), "variants must be a mapping")
    for name, v in doc["variants"].items():
        need(isinstance(v, dict) and set(v) == {"translation_m", "rotation_deg", "lost_frames_pct", "ms_per_frame"},
             f"variant {name}: needs translation_m, rotation_deg, lost_frames_pct, ms_per_frame")
        for part in ("translation_m", "rotation_deg"):
            need(isinstance(v[part], dict) and set(v[part]) == set(STAT_KEYS), f"variant {name}: {part} needs {STAT_KEYS}")
            need(all(isinstance(x, float) for x in v[part].values()), f"variant {name}: {part} values must be floats")
        need(isinstance(v["lost_frames_pct"], float), f"variant {name}: lost_frames_pct must be a float")
        need(v["ms_per_frame"] is None or isinstance(v["ms_per_frame"], float),
             f"variant {name}: ms_per_frame must be a float or null")


def save_summary(path, doc: dict) -> None:
    """Write the validated summary as strict JSON, an undefined statistic as ``null``."""
    validate_summary(doc)
    out = _map_statistics(doc, _finite_or_none)
    out["variants"] = {name: {**v, "ms_per_frame": _finite_or_none(v["ms_per_frame"])} for name, v in out["variants"].items()}
    Path(path).write_text(json.dumps(out, indent=2, allow_nan=False) + "\n")


def _finite_or_none(x):
    return x if x is not None and np.isfinite(x) else None


def strict_json(obj, indent: int = 2) -> str:
    """``obj`` as strict JSON (which has no NaN or Infinity): a non-finite float is ``null``."""

    def clean(x):
        if isinstance(x, float):
            return _finite_or_none(x)
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        return x

    return json.dumps(clean(obj), indent=indent, allow_nan=False)


def load_summary(path) -> dict:
    """The summary written by :func:`save_summary` (``null`` statistics read back as NaN), validated."""
    doc = json.loads(Path(path).read_text())
    if isinstance(doc, dict) and isinstance(doc.get("variants"), dict):
        doc = _map_statistics(doc, lambda x: float("nan") if x is None else x)
    validate_summary(doc)
    return doc


def _map_statistics(doc: dict, f) -> dict:
    """``doc`` with ``f`` applied to each statistic of each variant's translation and rotation."""
    variants = {}
    for name, v in doc["variants"].items():
        if isinstance(v, dict):
            v = {k: {stat: f(x) for stat, x in part.items()} if k in ("translation_m", "rotation_deg")
                 and isinstance(part, dict) else part for k, part in v.items()}
        variants[name] = v
    return {**doc, "variants": variants}


def write_report(out_dir, sequence: str, errors_by_variant: dict[str, dict[str, np.ndarray]], appendix: str = "") -> str:
    """Translation and rotation tables (text + CSV) and plots into ``out_dir``; ``appendix``
    (e.g. a coverage table) ends ``tables.txt``. Returns the text of ``tables.txt``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    parts, kinds = [], (("translation", TRANSLATION_COLUMNS, "m"), ("rotation", ROTATION_COLUMNS, "deg"))
    for kind, columns, unit in kinds:
        table = statistics_table(errors_by_variant, columns)
        parts.append(format_table(table, f"{sequence}: {kind} error ({unit})"))
        write_table_csv(out / f"{kind}_error.csv", table)
    parts.append(frames_scored(errors_by_variant))
    text = "\n\n".join(parts + ([appendix] if appendix else []))
    (out / "tables.txt").write_text(text + "\n")
    for kind, columns, unit in kinds:  # last: a figure that fails loses no table
        plot_errors(out / f"{kind}_error.png", errors_by_variant, columns, unit)
    return text
