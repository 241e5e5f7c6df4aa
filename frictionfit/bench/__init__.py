"""Speed against error: benchmarks of fitting, uncertainty and classification.

Each sub-module measures one stage and returns a ``dict`` with a ``summary``;
:mod:`frictionfit.bench.timing` holds the shared rules (same run, alternating,
median of repetitions, compile time apart, machine facts recorded).
"""
