"""The results index's claims table is the one the archived reports compute
(docs/results/scripts/claims_table.py), so a rebuilt report cannot leave it stale."""

from __future__ import annotations

import contextlib
import io
import runpy
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs" / "results"


def test_claims_table_in_the_index_is_the_computed_one() -> None:
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        runpy.run_path(str(DOCS / "scripts" / "claims_table.py"), run_name="__main__")
    table = [line for line in printed.getvalue().splitlines() if line.startswith("|")]
    assert len(table) > 10  # the header, the rule and one row per claim
    index = (DOCS / "README.md").read_text().splitlines()
    start = index.index(table[0])  # ValueError: the index lost the table's header
    shown = index[start : start + len(table)]
    for computed, written in zip(table, shown, strict=True):
        assert written == computed, "rerun docs/results/scripts/claims_table.py into the index"
