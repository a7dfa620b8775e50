"""Magnetic ball-chain catheter simulation on Drake.

The layers live in sub-packages: ``ballchain.drake_models`` (physics and models),
``ballchain.optimization`` (MathematicalProgram problems), ``ballchain.systems`` (LeafSystems and
diagrams); ``ballchain.cli`` is the ``ballchain`` command.
"""

__version__ = "0.1.0"
