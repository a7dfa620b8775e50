"""A world that is not the model: the perturbations the planner, the navigator's force model and
the simulated operator do not know (issue 43).

Every model of the station (the planner's inverse statics, the navigator's ``TipForceEstimator``,
the engine that plays the world) is built from the same nominal numbers. A real procedure meets
magnets whose magnetisation and axis differ from their data sheet, a cart placed a few
millimetres off, a chain whose balls differ by their grinding tolerance, an anatomy registered
from CT to the tracker with millimetres of error, and a tracker with a bias near metal.
``WorldMagnitudes`` holds how large each of these is, ``draw_world`` draws one world from a seed
with Drake's randomness (``pydrake.common.RandomGenerator``, a ``RANDOM_GAUSSIAN`` or
``RANDOM_UNIFORM`` symbolic variable evaluated with it: reproducible), and ``WorldDraw`` is the
drawn world, which ``systems.world_apply`` applies where the station builds the physics (the
quasi-static engine's magnets, chain, sheath and wall) and where the tracker measures the tip.

The perturbations (``PERTURBATIONS``, in draw order; each drawn whether or not it is chosen, so
that a world with one perturbation alone has the same value of it as the world with all):

* ``magnet_position``, normal, 2.0 mm per axis per unit magnet: an assumption (a cart's
  placement; the issue's "2 mm at 10 cm"); no published figure was found.
* ``magnet_axis``, normal, 1.0 deg per axis (a rotation vector) per unit magnet: K&J Magnetics
  (sintered NdFeB's magnetisation axis "within a few degrees, less than 5 deg"); 1 deg is an
  assumption below that bound.
* ``magnet_magnetisation``, uniform, +-1.4 % of Br per unit magnet: N52 Br 1.42-1.46 T
  (Shanghai Magnet's grade table), 14.5-14.8 kG (K&J Magnetics' specifications).
* ``ball_diameter``, uniform, +-0.05 mm (one lot: every ball): ground sintered NdFeB +-0.05 mm
  (Mainrich, "NdFeB magnet tolerances"; Kyle Magnet).
* ``ball_remanence``, uniform, +-1.4 % of Br (one lot): as ``magnet_magnetisation``.
* ``sheath_exit``, normal, 1.0 mm per axis, across the sheath's axis: CARTO 3 point
  localisation 0.46 +- 0.17 mm, registration offset 1.62 +- 0.77 mm in a phantom (Bourier et
  al., J Cardiovasc Electrophysiol 2014;25:74-83).
* ``anatomy_position``, normal, 1.56 mm per axis (2.7 mm in 3-D), the wall and the sheath in it
  together: CT/MR-to-CARTO integration error 2.7 +- 0.7 mm (Taclas et al., Heart Rhythm 2010,
  PMID 20122877); 1.62 +- 0.77 mm in a phantom (Bourier 2014).
* ``anatomy_scale``, normal, 2 %, about the sheath exit: an assumption (CT at another phase or
  rhythm than the procedure).
* ``localisation_bias``, normal, 1.0 mm per axis: an assumption; the NDI Aurora's 0.70 mm RMS
  is for an undisturbed volume, a C-arm distorts EM tracking by millimetres (Yaniv et al., Med
  Phys 2009; Cavaliere and Cantillon-Murphy, IJCARS 2022: 12-25 mm before compensation).
* ``anatomy_rotation``, normal, 1.5 deg per axis (a rotation vector; 2.6 deg in 3-D), the wall
  turned about the sheath exit: an **assumption**. No published distribution of the rotational
  part of a CT-to-EAM registration was found. It is bounded by: an uncorrected in-plane rotation
  of 8 deg (a patient positioned otherwise than at the CT) gave target errors of 2.94 mm and
  5.60 mm at 20 and 30 mm from the centre (Sra et al., "Cardiac image registration: rotational
  error correction and gated stabilization for cardiac motion", J Atr Fibrillation 2011;
  after correction it is not the main error); and by the 2.7 +- 0.7 mm integration error (Taclas
  2010): 1.5 deg per axis moves a wall point 40 mm from the septum by 1.5 mm RMS across the
  radius. Drawn last, so that the other perturbations keep the values the earlier worlds drew.

Not here: the wall's stiffness and friction (not modelled: rigid wall). The quasi-static engine's wall is rigid and
frictionless (``optimization.wall_constraints``): the press's force is set by the magnets' torque
and the chain, not by the wall's stiffness, and no friction is modelled; the plant engine has
both (``ContactConfig``) but the world applies to the quasi-static engine only.
The anatomy's rotation is applied by ``PosedWall`` (the grid stays axis-aligned: the query points
go into the grid's frame, the normals come back); a wall posed so is not a grid the compiled
kernels read, so the engine's solves take the Python statics (slower, the same law).
docs/guide/world.md tabulates all this.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np

from ballchain.infrastructure.errors import UserInputError, short_repr

# The perturbations, in draw order: (name, law, unit of the magnitude, what it is).
PERTURBATIONS = (
    ("magnet_position", "normal", "mm", "each unit magnet's centre, per axis"),
    ("magnet_axis", "normal", "deg", "each unit magnet's dipole turned by a fixed rotation, per axis"),
    ("magnet_magnetisation", "uniform", "%", "each unit magnet's remanence"),
    ("ball_diameter", "uniform", "mm", "the chain's ball diameter (one lot)"),
    ("ball_remanence", "uniform", "%", "the chain's remanence (one lot)"),
    ("sheath_exit", "normal", "mm", "the sheath exit's registration across its axis, per axis"),
    ("anatomy_position", "normal", "mm", "the anatomy's registration (the wall and the sheath in it moved), per axis"),
    ("anatomy_scale", "normal", "%", "the anatomy's scale about the sheath exit"),
    ("localisation_bias", "normal", "mm", "a constant bias of the tip tracker, per axis"),
    ("anatomy_rotation", "normal", "deg", "the anatomy's registration rotation about the sheath exit, per axis"),
)
NOT_MODELLED = {  # asked for by issue 43, absent from the quasi-static engine (docs/guide/world.md)
    "wall_stiffness": "not modelled: rigid wall (optimization.wall_constraints: a hard row sdf >= r)",
    "wall_friction": "not modelled: frictionless wall (the wall's push is along its normal only)",
}
NAMES = tuple(p[0] for p in PERTURBATIONS)
MAX_MAGNITUDE = {"mm": 20.0, "deg": 20.0, "%": 20.0}  # beyond these the model's assumptions end


@dataclass(frozen=True)
class WorldMagnitudes:
    """How large each perturbation is (module docstring: laws and sources). A ``normal`` one is
    its standard deviation, a ``uniform`` one its half-width (the tolerance); 0: none.

    Attributes:
        magnet_position: [mm]; magnet_axis: [deg]; magnet_magnetisation: [%];
        ball_diameter: [mm]; ball_remanence: [%]; sheath_exit: [mm]; anatomy_position: [mm];
        anatomy_scale: [%]; localisation_bias: [mm]; anatomy_rotation: [deg].
    """

    magnet_position: float = 0.0
    magnet_axis: float = 0.0
    magnet_magnetisation: float = 0.0
    ball_diameter: float = 0.0
    ball_remanence: float = 0.0
    sheath_exit: float = 0.0
    anatomy_position: float = 0.0
    anatomy_scale: float = 0.0
    localisation_bias: float = 0.0
    anatomy_rotation: float = 0.0

    def __post_init__(self) -> None:
        for name, _, unit, _ in PERTURBATIONS:
            value = getattr(self, name)
            hi = MAX_MAGNITUDE[unit]
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) \
                    or not 0.0 <= value <= hi:
                raise UserInputError(f"world {name} must be a number in 0..{hi:g} {unit}, got {short_repr(value)}")

    def only(self, names) -> "WorldMagnitudes":
        """These magnitudes with every perturbation not in ``names`` set to 0."""
        for name in names:
            if name not in NAMES:
                raise UserInputError(f"world only: {short_repr(name)} is not a perturbation; choose from "
                                     f"{', '.join(NAMES)}")
        return replace(self, **{name: 0.0 for name in NAMES if name not in names})

    def to_dict(self) -> dict:
        return asdict(self)


PRESETS = {
    "none": WorldMagnitudes(),
    "literature": WorldMagnitudes(magnet_position=2.0, magnet_axis=1.0, magnet_magnetisation=1.4,
                                  ball_diameter=0.05, ball_remanence=1.4, sheath_exit=1.0,
                                  anatomy_position=2.7 / math.sqrt(3.0), anatomy_scale=2.0, localisation_bias=1.0,
                                  anatomy_rotation=1.5),
}


def preset(name: str) -> WorldMagnitudes:
    """A named preset (``PRESETS``): "none" (the perfect world) or "literature"."""
    if name not in PRESETS:
        raise UserInputError(f"world preset must be one of {', '.join(PRESETS)}, got {short_repr(name)}")
    return PRESETS[name]


def _rotation_vector_matrix(w: np.ndarray) -> np.ndarray:
    """Rodrigues: the rotation by |w| [rad] about w."""
    angle = float(np.linalg.norm(w))
    if angle == 0.0:
        return np.eye(3)
    k = w / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


@dataclass(frozen=True)
class WorldDraw:
    """One drawn world (SI inside; ``to_dict`` in mm, deg, %).

    Attributes:
        magnet_offsets: per unit magnet, its centre's error (3,) [m].
        magnet_tilts: per unit magnet, the rotation vector (3,) [rad] that turns its dipole (fixed in
            the world: a tilt in the magnet's body would turn with it; the angle between the true
            and the nominal dipole is of the same size).
        magnet_scales: per unit magnet, its remanence over the nominal.
        ball_diameter_scale, ball_remanence_scale: the chain's over the nominal.
        sheath_exit_offset: (3,) [m]; anatomy_offset: (3,) [m]; anatomy_scale: over the nominal.
        localisation_bias: (3,) [m].
        seed: the RandomGenerator's seed; magnitudes: what it was drawn with.
        anatomy_rotation: (3,) [rad] the rotation vector that turns the wall about the sheath
            exit (``anatomy_rotation_matrix``).
    """

    magnet_offsets: tuple = ()
    magnet_tilts: tuple = ()
    magnet_scales: tuple = ()
    ball_diameter_scale: float = 1.0
    ball_remanence_scale: float = 1.0
    sheath_exit_offset: tuple = (0.0, 0.0, 0.0)
    anatomy_offset: tuple = (0.0, 0.0, 0.0)
    anatomy_scale: float = 1.0
    localisation_bias: tuple = (0.0, 0.0, 0.0)
    seed: int = 0
    magnitudes: WorldMagnitudes = field(default_factory=WorldMagnitudes)
    anatomy_rotation: tuple = (0.0, 0.0, 0.0)

    @property
    def perturbed(self) -> bool:
        """Whether anything differs from the nominal world."""
        return any(v != 0.0 for v in self.magnitudes.to_dict().values())

    def magnet_rotation(self, k: int) -> np.ndarray:
        """(3, 3) the rotation of magnet k's magnetisation axis (identity when not drawn)."""
        return _rotation_vector_matrix(np.asarray(self.magnet_tilts[k], float)) if self.magnet_tilts else np.eye(3)

    def anatomy_rotation_matrix(self) -> np.ndarray:
        """(3, 3) the anatomy's registration rotation (identity when not drawn)."""
        return _rotation_vector_matrix(np.asarray(self.anatomy_rotation, float))

    def to_dict(self) -> dict:
        """The drawn world in mm, deg and % (JSON); ``not_modelled``: what issue 43 asks for that
        the engine has no parameter for (``NOT_MODELLED``)."""
        mm = lambda v: [round(1e3 * float(x), 4) + 0.0 for x in v]  # noqa: E731 (+ 0.0: no -0.0)
        return {"seed": self.seed, "magnitudes": self.magnitudes.to_dict(),
                "magnet_offsets_mm": [mm(v) for v in self.magnet_offsets],
                "magnet_tilts_deg": [round(math.degrees(float(np.linalg.norm(v))), 4) for v in self.magnet_tilts],
                "magnet_magnetisation_pct": [round(100.0 * (s - 1.0), 4) for s in self.magnet_scales],
                "ball_diameter_mm": round(1e3 * (self.ball_diameter_scale - 1.0) * NOMINAL_BALL_DIAMETER, 5),
                "ball_remanence_pct": round(100.0 * (self.ball_remanence_scale - 1.0), 4),
                "sheath_exit_offset_mm": mm(self.sheath_exit_offset), "anatomy_offset_mm": mm(self.anatomy_offset),
                "anatomy_scale_pct": round(100.0 * (self.anatomy_scale - 1.0), 4),
                "localisation_bias_mm": mm(self.localisation_bias),
                "anatomy_rotation_deg": [round(math.degrees(float(x)), 4) + 0.0 for x in self.anatomy_rotation],
                "anatomy_rotation_angle_deg": round(math.degrees(float(np.linalg.norm(self.anatomy_rotation))), 4),
                "not_modelled": dict(NOT_MODELLED)}


NOMINAL_BALL_DIAMETER = 3.175e-3  # [m]: ``params.BallChain``'s; the ball_diameter magnitude is in mm of it


def draw_world(magnitudes: WorldMagnitudes, seed: int, n_magnets: int) -> WorldDraw:
    """One world drawn from ``RandomGenerator(seed)`` (reproducible), every perturbation drawn in
    ``PERTURBATIONS`` order whatever its magnitude (a zero magnitude multiplies its draw), so a
    perturbation has the same value alone as with the others.

    Raises:
        UserInputError: a bad seed or number of magnets.
    """
    from pydrake.common import RandomGenerator  # lazy: pydrake is 0.5 s to import
    from pydrake.symbolic import Expression, Variable  # lazy: as above

    if not isinstance(magnitudes, WorldMagnitudes):
        raise UserInputError(f"draw_world magnitudes must be a WorldMagnitudes, got {short_repr(magnitudes)}")
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or not 0 <= seed <= 2**32 - 1:
        raise UserInputError(f"world seed must be an integer in 0..{2**32 - 1}, got {short_repr(seed)}")
    if isinstance(n_magnets, bool) or not isinstance(n_magnets, numbers.Integral) or n_magnets < 0:
        raise UserInputError(f"draw_world n_magnets must be an integer >= 0, got {short_repr(n_magnets)}")
    generator = RandomGenerator(int(seed))
    gauss = Expression(Variable("g", Variable.Type.RANDOM_GAUSSIAN))
    unit = Expression(Variable("u", Variable.Type.RANDOM_UNIFORM))

    def normal(size: int) -> np.ndarray:
        return np.array([gauss.Evaluate(generator=generator) for _ in range(size)])

    def uniform(size: int) -> np.ndarray:  # on [-1, 1)
        return np.array([2.0 * unit.Evaluate(generator=generator) - 1.0 for _ in range(size)])

    m = magnitudes
    offsets, tilts, scales = [], [], []
    for _ in range(n_magnets):  # per magnet: position, tilt, magnetisation
        offsets.append(tuple(1e-3 * m.magnet_position * normal(3)))
        tilts.append(tuple(math.radians(m.magnet_axis) * normal(3)))
        scales.append(1.0 + 0.01 * m.magnet_magnetisation * float(uniform(1)[0]))
    d_scale = 1.0 + 1e-3 * m.ball_diameter * float(uniform(1)[0]) / NOMINAL_BALL_DIAMETER
    br_scale = 1.0 + 0.01 * m.ball_remanence * float(uniform(1)[0])
    sheath = tuple(1e-3 * m.sheath_exit * normal(3))
    anatomy = tuple(1e-3 * m.anatomy_position * normal(3))
    scale = 1.0 + 0.01 * m.anatomy_scale * float(normal(1)[0])
    bias = tuple(1e-3 * m.localisation_bias * normal(3))
    rotation = tuple(math.radians(m.anatomy_rotation) * normal(3))  # last: the earlier draws keep their values
    return WorldDraw(tuple(offsets), tuple(tilts), tuple(scales), d_scale, br_scale, sheath, anatomy, scale, bias,
                     int(seed), m, rotation)


def magnitudes_from(values: dict) -> WorldMagnitudes:
    """A ``WorldMagnitudes`` from a mapping of some of its fields (the others 0)."""
    known = {f.name for f in fields(WorldMagnitudes)}
    for name in values:
        if name not in known:
            raise UserInputError(f"world magnitudes: unknown perturbation {short_repr(name)}; choose from "
                                 f"{', '.join(NAMES)}")
    return WorldMagnitudes(**values)


class PosedWall:
    """A wall (a signed distance ``sdf(p, gradient, hessian)``: an ``AtriumSDF`` grid, a plane)
    posed rigidly: a point q of the wall's own frame is at ``R q + t`` in the world, so
    ``posed(p) = inner(R^T (p - t))``, its gradient ``R grad`` and its Hessian ``R H R^T``. The
    anatomy's registration rotation (``systems.world_apply.perturbed_wall``): the inner grid stays
    axis-aligned, the query points go into its frame and the normals come back.

    Attributes:
        inner: the wall in its own frame; R: (3, 3) rotation; t: (3,) [m].
    """

    def __init__(self, inner, R, t):
        self.inner = inner
        self.R = np.asarray(R, float).reshape(3, 3)
        self.t = np.asarray(t, float).reshape(3)

    @classmethod
    def about(cls, inner, R, centre) -> "PosedWall":
        """``inner`` turned by R about the point ``centre`` (3,) [m] (which stays where it is)."""
        R = np.asarray(R, float).reshape(3, 3)
        c = np.asarray(centre, float).reshape(3)
        return cls(inner, R, c - R @ c)

    def translated(self, offset) -> "PosedWall":
        """The same wall moved rigidly by ``offset`` (3,) [m] (``wall_motion``)."""
        return PosedWall(self.inner, self.R, self.t + np.asarray(offset, float))

    def __call__(self, p, gradient: bool = True, hessian: bool = False):
        p = np.atleast_2d(np.asarray(p, float))
        q = (p - self.t) @ self.R  # R^T (p - t), row by row
        if not gradient and not hessian:
            return self.inner(q, gradient=False)
        out = self.inner(q, gradient=True, hessian=hessian)
        grad = out[1] @ self.R.T
        if not hessian:
            return out[0], grad
        return out[0], grad, np.einsum("ia,kab,jb->kij", self.R, out[2], self.R)
