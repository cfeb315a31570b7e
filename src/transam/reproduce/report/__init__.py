"""``transam report``: results.json, marl_eval.json, figures and report.md for a grid directory
(see :mod:`transam.reproduce.grid`), with the paper's claims checked against the results:
:mod:`~transam.reproduce.report.load` reads the runs, :mod:`~.aggregate` and :mod:`~.stats`
compute the cells, :mod:`~.claims` the verdicts, :mod:`~.results` results.json,
:mod:`~.markdown` report.md, :mod:`~.figures` the figures, and :mod:`~.build` writes them."""
