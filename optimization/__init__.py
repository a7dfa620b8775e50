"""The MathematicalProgram problems: the chain's statics and their inverse, and magnet sizing.

``statics`` (``ChainStatics``: the equilibrium shape as the minimum of the chain's energy),
``inverse_statics`` (magnet orientations that press the tip on a wall target),
``wall_constraints`` (the atrium's wall and the sheath as constraint rows), ``reduced_chain``
(the energy in reduced coordinates), ``naive_statics`` (the SLSQP baseline), ``sizing`` (the
clinical actuation magnet's size), ``warm_up`` (the kernels compiled up front). The public names are re-exported by ``ballchain``
(``ballchain.__all__``); the rest is private by convention.
"""
