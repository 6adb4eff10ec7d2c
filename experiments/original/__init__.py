"""The original SWAT trainer beside swat_jax, shared by ``against_original`` (curves and wall clock) and
``time_to_return`` (machine seconds to the original's final return): :mod:`~experiments.original.runs`
(both sides' runs), :mod:`~experiments.original.curves` (their curves on one grid),
:mod:`~experiments.original.returns` (final returns, Welch's test, time to a return) and
:mod:`~experiments.original.speed` (throughput at the paper's sizes).
"""
