"""Benchmarks of the pieces, each printing ratios against a baseline measured in the same run
(``python -m experiments.benchmarks.<name> --help``): ``env`` (the multi-task step against MuJoCo C),
``update`` (the TD3 update), ``network``, ``presets`` (end-to-end training throughput), ``rounds``,
``seeds``, ``sharding``, ``export``, ``variants``, ``compile_time`` and ``gpu_report`` (all of them on a GPU).
"""
