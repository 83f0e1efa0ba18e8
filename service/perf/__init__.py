"""Benchmarks: each measures figures side by side in one run and returns one JSON-able dict.

They are run by ``evcbench bench <name> --json``, never as timed assertions in the tests. Each is
registered in pyproject.toml ([project.entry-points."evcbench.benchmarks"], name -> module:function),
where the CLI finds it and imports it alone, so one benchmark's dependencies never slow another.
"""
