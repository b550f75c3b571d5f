"""Markdown tables: one format for every results file and the parameter table of docs/node.md."""

from hjrno_ros.core.tables import markdown_table, records_table


def test_markdown_table_has_a_header_a_rule_and_one_line_per_row():
    assert markdown_table(["a", "b"], [[1, "x"], [2.5, None]]) == [
        "| a | b |", "| --- | --- |", "| 1 | x |", "| 2.5 | None |"]


def test_records_table_takes_the_first_records_keys_and_blanks_missing_cells():
    rows = [{"n": 1, "v": None}, {"n": 2}]
    assert records_table(rows) == ["| n | v |", "| --- | --- |", "| 1 | None |", "| 2 |  |"]
    assert records_table(rows, ["v"], blank_none=True) == ["| v |", "| --- |", "|  |", "|  |"]
