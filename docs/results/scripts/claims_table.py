"""The paper's claims, environment by environment: each archived grid's computed verdicts
(`transam report`'s results.json) side by side, so one table says which claim holds where.

A cell is that grid's per-environment verdict; "(k/n)" when only k of its n checks could run
(a method not trained there yet), "-" where the claim names no such environment (the paper's
ablation table is Spread's only). Rebuild each grid's report first (`transam report DIR`).

    python docs/results/scripts/claims_table.py
"""

from __future__ import annotations

import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# column title -> (grid folder under docs/results, environment)
GRIDS = {
    "Spread 10M, authors' population": ("paper-budget", "spread"),
    "Spread 1M (2026-12-02)": ("medium", "spread"),
    "Tag 3M": ("tag", "tag"),
    "Overcooked 1.5M": ("overcooked", "overcooked"),
    "LBF 4M": ("lbf", "lbf"),
}


def cell(claim: dict, env: str) -> str:
    """One grid's verdict on one claim, with how many of its checks ran."""
    found = claim["per_env"].get(env)
    if found is None:
        return "-"
    checks = found["checks"]
    ran = sum(c["verdict"] != "not run" for c in checks)
    verdict = found["verdict"]
    if ran == 0:
        return "not run"
    return verdict if ran == len(checks) else f"{verdict} ({ran}/{len(checks)})"


def main() -> None:
    reports = {
        title: json.loads((ROOT / folder / "grid" / "report" / "results.json").read_text())
        for title, (folder, _) in GRIDS.items()
    }
    by_key = {t: {c["key"]: c for c in r["claims"]} for t, r in reports.items()}
    claims = next(iter(reports.values()))["claims"]
    print("| claim | " + " | ".join(GRIDS) + " |")
    print("|---|" + "---|" * len(GRIDS))
    for claim in claims:
        row = [cell(by_key[t][claim["key"]], env) for t, (_, env) in GRIDS.items()]
        print(f"| `{claim['key']}` ({claim['where']}) | " + " | ".join(row) + " |")
    dates = ", ".join(f"{t}: {r['generated']}" for t, r in reports.items())
    print(f"\nreports generated {dates}")


if __name__ == "__main__":
    main()
