"""Experiments (tasks × methods × seeds, resumable, local or Ray), their statistics and reports,
and ``itskill learn``, the whole method end to end on a new command.

- :mod:`itskill.experiments.config`: experiment TOML files, validated;
- :mod:`itskill.experiments.runner`: the cells as jobs, a resumable run directory;
- :mod:`itskill.experiments.analysis`: curves over seeds, Table II, time to threshold, gains;
- :mod:`itskill.experiments.plots` and :mod:`itskill.experiments.document`: figures, Markdown/HTML;
- :mod:`itskill.experiments.report`: the experiment report and the ``itskill learn`` report;
- :mod:`itskill.experiments.learn`: the end-to-end pipeline and its budgets (``data/learn.toml``).
"""
