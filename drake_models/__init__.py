"""The physical world: parameters, the dipole laws, field sources, the chain's energy, models.

Everything here is SI (m, T, A m^2, N, J). Nothing here imports from the other layers.
"""
