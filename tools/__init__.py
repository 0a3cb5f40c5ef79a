"""Scripts that are not part of the API: benchmarks against peers, tables, figures (`python -m tools.NAME`)."""
