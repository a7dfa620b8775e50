"""External magnetic field sources and their superposition.

A field source answers ``field_and_gradient(p_W) -> (B_W, G_W)`` for (k, 3) points in world:
the flux density (k, 3) [T] and its gradient ``G[k, a, b] = dB_a/dp_b`` (k, 3, 3) [T/m].
Sources: a uniform field, a permanent magnet (cylinder or sphere) modelled as a point dipole or,
for the cylinder, with magpylib's exact closed-form field, and a sum of any of these.

How far apart the dipole and exact models of the prototype cylinder are is measured by
``ballchain field-models`` (see README).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar, Literal, Protocol, Sequence

import numpy as np

from ballchain.drake_models.kernels import dipole_field_and_gradient
from ballchain.drake_models.kernels.external import GRADIENT_STEP
from ballchain.drake_models.kernels.external import field_gradient_derivative as _field_gradient_derivative
from ballchain.drake_models.dipole import DipoleFieldAtPoint, dipole_field, dipole_field_of_checked
from ballchain.drake_models.params import CylinderMagnet, SphereMagnet
from ballchain.drake_models.vectors import perpendicular_basis
from ballchain.infrastructure.arg_checks import as_array, as_vector, require_choice, require_type
from ballchain.infrastructure.errors import UserInputError, check_in, short_repr

FieldModel = Literal["dipole", "exact"]

# The strongest field a source of the API (and every --field-mT flag) may give [T]: a
# catheter's actuation fields are tens of mT (the paper's 23 mT), an MRI scanner's 1.5..3 T
# are not steering fields. "23" for 23 mT is 23 T: refused with this bound in the message.
MAX_FIELD_T = 1.0
MAX_FD_STEP = 1e-3  # [m]: the exact model's central-difference step (1e-5 by default); a ball is 3..6 mm


class FieldSource(Protocol):
    """What a magnetic field source is to the statics, the wrench system and the kernels: one method.

    A new source (a coil model, a measured field map) is any object with
    ``field_and_gradient``; it need not inherit from this class (a structural protocol, as
    ``UniformField``, ``MagnetSource`` and ``FieldSources`` are). ``ChainStatics.solve``,
    ``ReducedChain`` and ``kernels.chain_wrenches`` take it as it is::

        class LinearField:  # B = B0 + G0 p, the same gradient everywhere
            def __init__(self, B0, G0):
                self.B0, self.G0 = np.asarray(B0, float), np.asarray(G0, float)

            def field_and_gradient(self, p_W):
                p = np.atleast_2d(p_W)
                return self.B0 + p @ self.G0.T, np.broadcast_to(self.G0, (len(p), 3, 3)).copy()

        bc.ChainStatics(bc.BallChain(n_balls=8)).solve(LinearField([0, 0.02, 0], np.zeros((3, 3))))

    Two optional members let a source skip work it knows is zero (the built-in sources use them,
    ``kernels.external``): ``uniform = True`` for a field that is ``B_W`` (3,) [T] everywhere with
    no gradient (``UniformField``), and ``field_gradient_derivative(p, step)`` for a source that
    computes its own second derivative (``FieldSources`` sums its parts'); without them the
    Newton statics' second derivative is the central difference of ``field_and_gradient``.
    """

    def field_and_gradient(self, p_W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The flux density and its gradient at some points.

        Args:
            p_W: (k, 3) points in the world frame [m].

        Returns:
            ``(B_W, G_W)``: B_W (k, 3) [T]; G_W (k, 3, 3) [T/m] with ``G_W[i, a, b] = dB_a / dp_b``
            at point i.
        """


def require_field_source(source, name: str, allow_none: bool = False):
    """``source`` when it is a field source (it has ``field_and_gradient``), else UserInputError."""
    if (source is None and allow_none) or callable(getattr(source, "field_and_gradient", None)):
        return source
    allowed = "UniformField, MagnetSource, FieldSources" + (" or None" if allow_none else "")
    raise UserInputError(f"{name} must be a field source ({allowed}), got {type(source).__name__} {short_repr(source)}")


def _as_points(p_W) -> np.ndarray:
    if isinstance(p_W, (str, bytes, dict)) or p_W is None:
        raise UserInputError(f"field points p_W must be (k, 3) finite numbers [m], got {short_repr(p_W)}")
    try:
        p = np.asarray(p_W, dtype=float)
    except (TypeError, ValueError):
        raise UserInputError(f"field points p_W must be (k, 3) finite numbers [m], got {short_repr(p_W)}") from None
    if p.ndim == 1:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"field points must have shape (k, 3), got {np.shape(p_W)}")
    if not np.all(np.isfinite(p)):
        raise ValueError("field points are not finite (NaN or inf)")
    return p


def rotation_with_z_along(direction) -> np.ndarray:
    """A rotation matrix R_WM whose third column is the unit vector along ``direction``."""
    z = as_vector(direction, "direction", nonzero=True)
    norm = np.linalg.norm(z)
    if not np.isfinite(norm) or norm == 0.0:
        raise UserInputError(f"direction must be a finite non-zero vector, got {direction!r}")
    z = z / norm
    return np.column_stack([*perpendicular_basis(z), z])


@dataclass
class UniformField:
    """A spatially uniform flux density ``B_W`` (3,) [T] (a Helmholtz/Maxwell-coil idealisation).

    Example:
        A 23 mT field along +y (``in_plane``: a magnitude and an angle from +x towards +y)::

            >>> import numpy as np, ballchain as bc
            >>> B, G = bc.UniformField.in_plane(0.023, np.radians(90.0)).field_and_gradient([[0.0, 0.0, 0.0]])
            >>> [round(1e3 * float(v), 3) for v in B[0]], float(np.abs(G).max())  # [mT], no gradient
            ([0.0, 23.0, 0.0], 0.0)
    """

    B_W: np.ndarray
    uniform: ClassVar[bool] = True  # the kernels take B_W as it is and skip the gradients (``FieldSource``)

    def __post_init__(self) -> None:
        self.B_W = as_vector(self.B_W, "UniformField.B_W", unit="T")
        if not np.all(np.isfinite(self.B_W)):
            raise UserInputError(f"UniformField.B_W must be finite, got {self.B_W}")
        magnitude = float(np.linalg.norm(self.B_W))
        if magnitude > MAX_FIELD_T:
            raise UserInputError(f"UniformField.B_W |B| = {magnitude:g} T must be at most {MAX_FIELD_T:g} T "
                                 f"({MAX_FIELD_T * 1e3:g} mT): it is in tesla (23 mT is 0.023), "
                                 f"got {short_repr(self.B_W.tolist())}")

    @staticmethod
    def in_plane(magnitude_T: float, angle_rad: float) -> "UniformField":
        """A field in the x-y plane at ``angle_rad`` from +x towards +y."""
        check_in("UniformField.in_plane magnitude_T", magnitude_T, -MAX_FIELD_T, MAX_FIELD_T, unit="T")
        check_in("UniformField.in_plane angle_rad", angle_rad, -math.inf, math.inf, unit="rad")
        return UniformField(magnitude_T * np.array([np.cos(angle_rad), np.sin(angle_rad), 0.0]))

    def field_and_gradient(self, p_W):
        """(B_W (k, 3) [T], G_W (k, 3, 3) [T/m]) at the points p_W (k, 3) [m]: the same field
        everywhere, no gradient."""
        p = _as_points(p_W)
        return np.broadcast_to(self.B_W, p.shape).copy(), np.zeros((p.shape[0], 3, 3))


@dataclass
class MagnetSource:
    """A permanent magnet at pose (p_WM, R_WM); its dipole points along the magnet frame's z.

    Attributes:
        magnet: a CylinderMagnet or SphereMagnet.
        p_WM: (3,) centre in world [m].
        R_WM: (3, 3) orientation; column 2 is the magnetisation direction.
        model: "dipole" (point dipole at the centre) or "exact" (magpylib's closed-form field of
            the cylinder; for a sphere the dipole field is already exact outside it).

    Example:
        The prototype's magnet 16.51 cm along +x, its dipole towards the origin: the point dipole and the
        exact cylinder at the origin::

            >>> import ballchain as bc
            >>> dipole = bc.MagnetSource.pointing(bc.CylinderMagnet(), [0.1651, 0.0, 0.0], [-1.0, 0.0, 0.0])
            >>> exact = bc.MagnetSource.pointing(bc.CylinderMagnet(), [0.1651, 0.0, 0.0], [-1.0, 0.0, 0.0], "exact")
            >>> [round(1e3 * float(s.field_and_gradient([[0.0, 0.0, 0.0]])[0][0, 0]), 2) for s in (dipole, exact)]  # [mT]
            [-8.85, -8.38]
    """

    magnet: CylinderMagnet | SphereMagnet
    p_WM: np.ndarray
    R_WM: np.ndarray = field(default_factory=lambda: np.eye(3))
    model: FieldModel = "dipole"
    fd_step: float = 1e-5  # central-difference step for the exact model's gradient [m]

    def __post_init__(self) -> None:
        require_type(self.magnet, (CylinderMagnet, SphereMagnet), "MagnetSource.magnet")
        self.p_WM = as_vector(self.p_WM, "MagnetSource.p_WM", unit="m")
        self.R_WM = as_array(self.R_WM, "MagnetSource.R_WM", (3, 3))
        require_choice(self.model, ("dipole", "exact"), "MagnetSource.model")
        check_in("MagnetSource.fd_step", self.fd_step, 0.0, MAX_FD_STEP, lo_open=True, unit="m")
        if not np.all(np.isfinite(self.p_WM)) or not np.all(np.isfinite(self.R_WM)):
            raise UserInputError("MagnetSource pose must be finite")
        if not np.allclose(self.R_WM.T @ self.R_WM, np.eye(3), atol=1e-6):
            raise UserInputError("MagnetSource.R_WM is not a rotation matrix")
        if np.linalg.det(self.R_WM) < 0.0:  # orthogonal, but a reflection: a left-handed magnet frame
            raise UserInputError("MagnetSource.R_WM is a reflection (determinant -1), not a rotation matrix")
        if self.model not in ("dipole", "exact"):
            raise UserInputError(f"MagnetSource.model must be 'dipole' or 'exact', got {self.model!r}")

    @classmethod
    def at_checked_pose(cls, magnet, p_WM: np.ndarray, R_WM: np.ndarray, model: FieldModel) -> "MagnetSource":
        """The source at a pose already checked, without ``__post_init__``'s checks.

        For a magnet unit's pose at every Hall sample: its centre and model were checked once
        (its ``MagnetUnitConfig``) and its rotation comes from its unit quaternion. The arrays
        are used as given (float, (3,) and (3, 3)): the same fields as the checked source's.
        """
        source = cls.__new__(cls)
        source.magnet, source.p_WM, source.R_WM, source.model, source.fd_step = magnet, p_WM, R_WM, model, cls.fd_step
        return source

    @staticmethod
    def pointing(magnet, p_WM, m_hat_W, model: FieldModel = "dipole") -> "MagnetSource":
        """A magnet at p_WM whose dipole points along m_hat_W."""
        return MagnetSource(magnet, p_WM, rotation_with_z_along(m_hat_W), model)

    @property
    def m_W(self) -> np.ndarray:
        """Dipole moment in world [A m^2]."""
        return self.magnet.dipole_moment * self.R_WM[:, 2]

    def _to_magnet_frame(self, p: np.ndarray) -> np.ndarray:
        p_M = (p - self.p_WM) @ self.R_WM
        inside = self.magnet.contains(p_M)
        if np.any(inside):
            k = int(np.argmax(inside))
            raise UserInputError(
                f"field point {p[k]} m lies inside the {type(self.magnet).__name__} centred at "
                f"{self.p_WM} m: a magnet cannot be placed on the chain"
            )
        return p_M

    def _exact_B_M(self, p_M: np.ndarray) -> np.ndarray:
        from magpylib.func import cylinder_field

        B = cylinder_field(
            "B",
            observers=p_M,
            dimensions=(self.magnet.diameter, self.magnet.length),
            polarizations=(0.0, 0.0, self.magnet.remanence),
            squeeze=False,
        )
        return np.asarray(B, dtype=float).reshape(p_M.shape)

    def field(self, p_W) -> np.ndarray:
        """Flux density (k, 3) [T] at the points p_W (k, 3)."""
        p = _as_points(p_W)
        p_M = self._to_magnet_frame(p)
        if self.model == "exact" and isinstance(self.magnet, CylinderMagnet):
            return self._exact_B_M(p_M) @ self.R_WM.T
        return dipole_field(p - self.p_WM, self.m_W)

    def field_beyond_reach(self, p_W: np.ndarray) -> np.ndarray:
        """``field`` (the same numbers) at points its caller has checked once: p_W (k, 3) float,
        finite, each farther from the centre than the magnet's ``bounding_radius`` (so outside
        the magnet at every orientation; ``beyond_reach`` says whether they are). For a sensor
        fixed near a turning magnet, sampled a hundred times a second."""
        if self.model == "exact" and isinstance(self.magnet, CylinderMagnet):
            return self._exact_B_M((p_W - self.p_WM) @ self.R_WM) @ self.R_WM.T
        return dipole_field_of_checked(p_W - self.p_WM, self.magnet.dipole_moment * self.R_WM[:, 2])

    def beyond_reach(self, p_W) -> bool:
        """Whether the points p_W (k, 3) are finite and farther from the centre than the magnet's
        bounding radius (``field_beyond_reach`` may be used at them, whatever the orientation)."""
        try:
            p = _as_points(p_W)
        except ValueError:
            return False
        return bool(np.all(np.linalg.norm(p - self.p_WM, axis=1) > self.magnet.bounding_radius))

    def field_and_gradient(self, p_W):
        """(B_W (k, 3) [T], G_W (k, 3, 3) [T/m]) at the points p_W (k, 3) [m]: the magnet's
        field by its ``model`` (the point dipole, or the exact cylinder)."""
        p = _as_points(p_W)
        p_M = self._to_magnet_frame(p)
        if self.model == "exact" and isinstance(self.magnet, CylinderMagnet):
            h = self.fd_step
            offsets = np.concatenate([np.eye(3) * h, -np.eye(3) * h])  # (6, 3)
            stencil = (p_M[:, None, :] + offsets[None, :, :]).reshape(-1, 3)
            if np.any(self.magnet.contains(stencil)):
                raise UserInputError(
                    f"a field point lies within {h} m of the magnet's surface: the exact "
                    "model's finite-difference gradient is undefined there"
                )
            B_all = self._exact_B_M(np.concatenate([p_M, stencil])).reshape(-1, 3)
            k = p_M.shape[0]
            B_M = B_all[:k]
            Bs = B_all[k:].reshape(k, 6, 3)
            G_M = ((Bs[:, :3, :] - Bs[:, 3:, :]) / (2 * h)).transpose(0, 2, 1)  # [k, a, b]
            R = self.R_WM
            return B_M @ R.T, np.einsum("ia,kab,jb->kij", R, G_M, R)
        # The point-dipole law of dipole.py as a compiled kernel (the numpy functions are its
        # tests' reference); _to_magnet_frame above has refused points inside the magnet.
        _, B, G = dipole_field_and_gradient(p, self.p_WM[None, :], self.m_W[None, :], np.zeros(1))
        return B, G


class FieldAtPoint:
    """One magnet's flux density at one fixed point, for any orientation of the magnet: what
    ``MagnetSource(magnet, p_WM, R_WM, model).field(p_W[None])[0]`` gives, the same numbers.

    For a sensor fixed near a turning magnet (a Hall sensor under its unit, sampled a hundred
    times a second): the magnet's centre, shape and model are checked by the caller once (a
    placed ``MagnetUnitConfig``), the point is checked here once, and what does not depend on
    the orientation (the point from the centre, its squared distance, the dipole moment) is
    computed once. Beyond the magnet's reach (``MagnetSource.beyond_reach``) a call is the law of
    ``MagnetSource.field_beyond_reach``; nearer, the checked ``MagnetSource.field``.
    """

    def __init__(self, magnet, p_WM: np.ndarray, model: FieldModel, p_W: np.ndarray) -> None:
        self._magnet, self._p_WM, self._model = magnet, np.asarray(p_WM, dtype=float), model
        self._p_W = _as_points(np.asarray(p_W, dtype=float).reshape(1, 3))
        source = MagnetSource.at_checked_pose(magnet, self._p_WM, np.eye(3), model)
        self.beyond_reach = source.beyond_reach(self._p_W)
        dipole = self.beyond_reach and not (model == "exact" and isinstance(magnet, CylinderMagnet))
        # field_beyond_reach's law: its r once, the moment's direction turning
        self._dipole = DipoleFieldAtPoint(self._p_W - self._p_WM) if dipole else None
        self._moment = magnet.dipole_moment

    @property
    def dipole(self) -> DipoleFieldAtPoint | None:
        """The point-dipole law a call evaluates (with the moment ``moment * R_WM[:, 2]``), or None
        when a call evaluates the magnet's own model (the exact one, or within its reach)."""
        return self._dipole

    @property
    def moment(self) -> float:
        """The magnet's dipole moment [A m^2]."""
        return self._moment

    def __call__(self, R_WM: np.ndarray) -> np.ndarray:
        """(3,) flux density [T] at the point with the magnet at orientation R_WM, a rotation
        matrix (3, 3) of floats (a magnet unit's state)."""
        if self._dipole is not None:
            return self._dipole(self._moment * R_WM[:, 2])
        source = MagnetSource.at_checked_pose(self._magnet, self._p_WM, R_WM, self._model)
        return (source.field_beyond_reach(self._p_W) if self.beyond_reach else source.field(self._p_W))[0]


@dataclass
class FieldSources:
    """Superposition of any number of field sources (the field of the sum is the sum of fields)."""

    sources: Sequence[FieldSource] = ()

    def __post_init__(self) -> None:
        require_type(self.sources, (list, tuple), "FieldSources.sources", "a list of field sources")
        for k, source in enumerate(self.sources):
            require_field_source(source, f"FieldSources.sources[{k}]")

    def field_and_gradient(self, p_W):
        """(B_W (k, 3) [T], G_W (k, 3, 3) [T/m]) at the points p_W (k, 3) [m]: the sum of the
        sources' fields and gradients."""
        p = _as_points(p_W)
        B = np.zeros((p.shape[0], 3))
        G = np.zeros((p.shape[0], 3, 3))
        for source in self.sources:
            b, g = source.field_and_gradient(p)
            B += b
            G += g
        return B, G

    def field_gradient_derivative(self, p_W, step: float = GRADIENT_STEP) -> np.ndarray:
        """The sum of the sources' ``field_gradient_derivative`` (k, 3, 3, 3) [T/m^2] at p_W (k, 3) [m]."""
        p = _as_points(p_W)
        total = np.zeros((p.shape[0], 3, 3, 3))
        for source in self.sources:
            total += field_gradient_derivative(source, p, step)
        return total


def field_gradient_derivative(source: FieldSource, p_W, step: float = GRADIENT_STEP) -> np.ndarray:
    """Second spatial derivative ``dG[k, a, b, c] = d2 B_a / dp_b dp_c`` (k, 3, 3, 3) [T/m^2].

    Zero for a uniform field; the sum of the parts' for ``FieldSources``; otherwise central
    differences of the source's analytic (or, for the exact cylinder, finite-difference)
    gradient (``kernels.external.field_gradient_derivative``). Used by the Newton statics' Hessian.
    """
    return _field_gradient_derivative(source, _as_points(p_W), step)
