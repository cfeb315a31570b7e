"""``transam report``: results.json, marl_eval.json, figures and report.md for a grid directory
(see :mod:`transam.grid`), with the paper's claims checked against the results."""

from transam.report.build import Report, build_report

__all__ = ["Report", "build_report"]
