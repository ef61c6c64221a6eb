"""Evaluation: pose errors, thesis-format statistics tables, plots, the JSON summary, scoring."""

from .report import (
    SummaryError,
    format_errors_by_depth,
    format_table,
    load_summary,
    make_summary,
    plot_errors,
    save_summary,
    statistics_table,
    validate_summary,
    variant_summary,
    write_report,
    write_table_csv,
)
from .score import align, score, score_files
from .statistics import ROTATION_COLUMNS, STAT_KEYS, TRANSLATION_COLUMNS, error_statistics, pose_errors

__all__ = [
    "ROTATION_COLUMNS",
    "STAT_KEYS",
    "TRANSLATION_COLUMNS",
    "SummaryError",
    "align",
    "error_statistics",
    "format_errors_by_depth",
    "format_table",
    "load_summary",
    "make_summary",
    "plot_errors",
    "pose_errors",
    "save_summary",
    "score",
    "score_files",
    "statistics_table",
    "validate_summary",
    "variant_summary",
    "write_report",
    "write_table_csv",
]
