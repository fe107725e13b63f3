"""Benchmarks of pipeline-sim (run with ``python -m benchmarks.run``; see run.py)."""
