"""Moved to ``ballchain.infrastructure.safe_files``: this old name is a shim for a release of grace.

Importing ``ballchain.drake_models.safe_files`` gives the module ``ballchain.infrastructure.safe_files`` itself
(the same object in ``sys.modules``), so every name, private ones included, is there and a
``monkeypatch.setattr`` through either name patches the one module. Import the new name.
"""

import sys

from ballchain.infrastructure import safe_files as _module

sys.modules[__name__] = _module
