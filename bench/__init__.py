"""The benchmark scripts (``python bench/codec.py`` ...) and the fuzz tool (``python -m bench.fuzz``).

A package so that the fuzz tool, itself a package, is imported by its tests (``tests/test_fuzz.py``)
and run with ``python -m`` from the repository's root. The scripts are run by their path.
"""
