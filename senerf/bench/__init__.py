"""Benchmark harness for ``senerf-fit`` (``senerf-bench``; no torch import): :mod:`~senerf.bench.protocols` (what to
run), :mod:`~senerf.bench.runner` (each fit a child process, local or Ray), :mod:`~senerf.bench.results` (one JSON
line per iteration), :mod:`~senerf.bench.summary` and :mod:`~senerf.bench.ladder` (statistics over seeds, paired
tests), :mod:`~senerf.bench.report` and :mod:`~senerf.bench.plots` (markdown, PNG), :mod:`~senerf.bench.cli`."""
