"""Benchmark commands that write sections of ``BENCHMARKS.md`` (``modalfem bench <name>``).

* ``modalfem.bench.cli``: the ``bench`` subcommand (``main(argv) -> int``).
* ``modalfem.bench.modes_bench``: the clamped-cantilever modes ladder, one case per subprocess.
* ``modalfem.bench.peers``: the peer recipes (dolfinx + SLEPc tutorial, scikit-fem + SciPy eigsh).

Benchmarks are commands, not tests: they measure ours and the peers in the same run and report
ratios, together with the machine and library versions.
"""

__all__: list[str] = []
