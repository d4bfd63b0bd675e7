"""Measurement harness for ovis (issue 4): per-frame cost, scaling, GA calibration time,
end-to-end latency and throughput over Zenoh, and bounded memory — each reported as a
ratio against a floor measured in the same run.

Run from the repository root: ``python -m benchmarks.run [--quick] [--only NAME...]``.
It writes ``benchmarks/results.json`` (the rows), ``benchmarks/machine.json`` (where they
were measured) and the table between the ``benchmarks`` markers of ``README.md``.

Benchmarks are not tests: nothing here asserts on timing.
"""
