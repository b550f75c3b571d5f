"""Markdown tables for the results files and docs: one format everywhere (a header, a ``---`` rule, rows)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any


def markdown_table(columns: Sequence[str], rows: Iterable[Sequence[Any]]) -> list[str]:
    """The lines of a Markdown table: ``columns`` as its header, each row's cells as ``str``."""
    return ["| " + " | ".join(columns) + " |", "|" + " --- |" * len(columns),
            *("| " + " | ".join(str(cell) for cell in row) + " |" for row in rows)]


def records_table(rows: Sequence[Mapping[str, Any]], keys: Sequence[str] | None = None,
                  blank_none: bool = False) -> list[str]:
    """A table of records: one column per key (``keys``, or the first record's); an empty cell where a record
    lacks a key, or (``blank_none``) holds None."""
    keys = list(rows[0]) if keys is None else list(keys)
    return markdown_table(keys, (["" if k not in r or (blank_none and r[k] is None) else r[k] for k in keys]
                                 for r in rows))
