"""Moved to ``ballchain.infrastructure.kernel_compiler``: this old name is a shim for a release of grace.

Importing ``ballchain.drake_models.kernel_compiler`` gives the module ``ballchain.infrastructure.kernel_compiler`` itself
(the same object in ``sys.modules``), so every name, private ones included, is there and a
``monkeypatch.setattr`` through either name patches the one module. Import the new name.
"""

import sys

from ballchain.infrastructure import kernel_compiler as _module

sys.modules[__name__] = _module
