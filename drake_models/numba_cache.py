"""Moved to ``ballchain.infrastructure.numba_cache``: this old name is a shim for a release of grace.

Importing ``ballchain.drake_models.numba_cache`` gives the module ``ballchain.infrastructure.numba_cache`` itself
(the same object in ``sys.modules``), so every name, private ones included, is there and a
``monkeypatch.setattr`` through either name patches the one module. Import the new name.
"""

import sys

from ballchain.infrastructure import numba_cache as _module

sys.modules[__name__] = _module
