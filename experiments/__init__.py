"""The paper's experiments, the comparison with the original trainer, and the benchmarks: a package run from
the repository's root as ``python -m experiments.<name>`` (``--help`` on each).

Experiments train runs and compare their curves (``paper``, ``against_original``, ``time_to_return``,
``variants``); :mod:`experiments.benchmarks` times the pieces. They share one home for what a measurement
needs: :mod:`experiments.machine` (what machine it ran on), :mod:`experiments.timing` (the timer) and
:mod:`experiments.workers` (a measurement in a fresh process). Results are committed under
``experiments/results/`` and in BENCHMARKS.md.
"""
