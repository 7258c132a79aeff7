"""Benchmarks run by `davio bench NAME`: one module each (NAME, HELP, add_arguments, run).

Every benchmark prints a table and, with --json, one JSON object on stdout; results and the
machine they ran on are recorded in BENCHMARKS.md.
"""
