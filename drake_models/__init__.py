"""The physical world: parameters, the dipole laws, field sources, the chain's energy, models.

Everything here is SI (m, T, A m^2, N, J). Nothing here imports from the layers above
(``optimization``, ``systems``, the top); below it is only ``ballchain.infrastructure``
(``tests/test_layers.py`` holds the rule). ``errors``, ``arg_checks``, ``safe_files``,
``safe_yaml``, ``input_files``, ``numba_cache`` and ``kernel_compiler`` here are shims of their
new homes in ``ballchain.infrastructure``, for a release of grace.
"""
