"""Benchmarks behind `make bench`.

Each module has ``run(quick=False) -> str`` (a markdown section).
"""
