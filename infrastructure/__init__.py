"""The project's infrastructure, below every layer: errors, argument checks, safe files, input files, YAML, numba's cache.

Nothing here knows physics or Drake: ``errors`` (``UserInputError``, ``OutputError``),
``arg_checks`` (the Python API's argument checks), ``input_files`` (the one check of every file a
user gives), ``safe_files`` (atomic result files, checked output paths), ``safe_yaml`` (the one
loader of user YAML), ``numba_cache`` and ``kernel_compiler`` (numba's on-disk cache made to heal
itself, and compilations a stop can end), ``resource_limits`` (open files, processes and memory:
checked before a run where cheap, one line when met). Every layer may import it (``drake_models`` ->
``optimization`` -> ``systems`` -> the top); it imports none of them (``tests/test_layers.py``).

The old homes in ``ballchain.drake_models`` (``ballchain.drake_models.errors`` and the others)
are shims for a release of grace: importing one gives this package's module itself.
"""
