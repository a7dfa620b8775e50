"""Three-axis Hall sensor under an actuation magnet, and the dipole-direction estimator.

The sensor (MLX90393-like) sits ``D`` below its unit's magnet centre on the world -z axis and
samples the total field there periodically: its own magnet, optionally the other units' magnets
and any extra sources, plus Gaussian noise, then saturation at its range and quantisation to its
least significant bit. The estimator inverts the dipole law with the *correct* inverse
``(3/2) e3 e3^T - I`` (see ``drake_models/dipole_inversion.py``; the paper's printed formula is
wrong off-axis by up to 37 deg).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from ballchain.infrastructure.arg_checks import require_int, require_type
from ballchain.drake_models.dipole_inversion import FieldInversion, refine_direction
from ballchain.infrastructure.errors import UserInputError, require_finite_fields
from ballchain.drake_models.field_sources import FieldAtPoint, FieldSource, FieldSources, MagnetSource
from ballchain.systems.randomness import SampleGenerators, SeededLeafSystem
from ballchain.systems.unit_config import MagnetUnitConfig


@dataclass(frozen=True)
class HallSensorSpec:
    """A 3-axis Hall sensor's data-sheet figures (defaults: an MLX90393 on its +-50 mT setting).

    Attributes:
        range_T: per-axis full scale; readings saturate at +-range_T [T].
        lsb_T: (3,) resolution of the x, y, z readings [T] (MLX90393 gain 0, RES 1:
            about 1.5 uT xy and 2.4 uT z).
        noise_std_T: standard deviation of the Gaussian noise on each axis [T].
        sample_rate_hz: samples per second [Hz].
    """

    range_T: float = 50e-3
    lsb_T: tuple[float, float, float] = (1.5e-6, 1.5e-6, 2.4e-6)
    noise_std_T: float = 3e-6
    sample_rate_hz: float = 100.0

    def __post_init__(self) -> None:
        require_finite_fields(self)
        if not (self.range_T > 0 and self.sample_rate_hz > 0 and self.noise_std_T >= 0):
            raise UserInputError(f"HallSensorSpec: range and sample rate must be > 0, noise >= 0: {self}")
        if len(self.lsb_T) != 3 or min(self.lsb_T) < 0:
            raise UserInputError(f"HallSensorSpec.lsb_T must be 3 values >= 0, got {self.lsb_T!r}")


def quantise_reading(B: np.ndarray, spec: HallSensorSpec) -> np.ndarray:
    """Saturate (3,) field [T] at the range and round to the LSB, as the ADC does."""
    # np.clip's numbers (NaN kept) without its Python wrapper: a third of a sample's cost.
    B = np.minimum(np.maximum(np.asarray(B, dtype=float), -spec.range_T), spec.range_T)
    lsb = np.asarray(spec.lsb_T, dtype=float)
    if min(spec.lsb_T) > 0:  # every axis rounded (np.round to 0 decimals is np.rint)
        return np.rint(B / lsb) * lsb
    out = B.copy()
    nz = lsb > 0
    out[nz] = np.round(B[nz] / lsb[nz]) * lsb[nz]
    return out


class HallSensor(SeededLeafSystem):
    """A periodically sampled 3-axis Hall sensor ``D`` below its unit's magnet.

    Input ports:
        X_WM: RigidTransform (abstract), pose of the sensor's own magnet.
        X_WM_<name>: RigidTransform (abstract), one per other unit whose field it also sees.

    Output ports:
        B_sensor_T: (3,) last sample (noisy, saturated, quantised) in world axes [T].

    State: discrete, ``B_sensor_T`` (3) and the sample counter (1), updated at
    ``spec.sample_rate_hz`` and once at initialisation (so the first reading exists at t = 0).

    Parameter: the noise seed (1; ``randomness.SeededLeafSystem``: its default is the ``seed``
    given, ``randomness.set_random_context`` draws another). Noise (with the unit's
    ``sensor_noise``) is drawn from ``numpy.random.default_rng((seed, sample_index))``
    (``randomness.SampleGenerators``: that generator, built faster): reproducible and a function
    of the context only.
    """

    def __init__(
        self,
        unit: MagnetUnitConfig,
        *,
        other_units: Sequence[MagnetUnitConfig] = (),
        extra_sources: Sequence[FieldSource] = (),
        spec: HallSensorSpec | None = None,
        seed: int = 0,
    ) -> None:
        """
        Args:
            unit: the sensor's own unit, placed (magnet, centre, field model, D; its
                ``sensor_noise`` adds Gaussian noise, off for exact tests).
            other_units: units whose magnets the sensor also sees (their poses come in ports).
            extra_sources: fixed field sources also seen (e.g. a uniform field).
            spec: sensor figures (MLX90393-like defaults).
            seed: the default noise seed, 0..2**32 - 1.
        """
        super().__init__()
        require_type(unit, MagnetUnitConfig, "HallSensor unit", "a MagnetUnitConfig")
        for k, other in enumerate(other_units):
            require_type(other, MagnetUnitConfig, f"HallSensor other_units[{k}]", "a MagnetUnitConfig")
        if spec is not None:
            require_type(spec, HallSensorSpec, "HallSensor spec", "a HallSensorSpec or None")
        require_int(seed, "HallSensor seed", 0)
        self._unit = unit.check_placed()
        self._others = tuple(o.check_placed() for o in other_units)
        self._extra = FieldSources(tuple(extra_sources))
        self._spec = spec or HallSensorSpec()
        self._noise = bool(unit.sensor_noise)
        self._p_WS = unit.p_WS[None, :]
        self._last_fields: list[tuple[bytes, np.ndarray] | None] = [None] * (1 + len(self._others))
        # Each magnet's field at the sensor as a function of its orientation (what does not turn
        # computed once; the sensor beyond the magnet's reach at every orientation checked once).
        self._fields = [FieldAtPoint(u.magnet, u.p_WM, u.model, unit.p_WS) for u in (self._unit, *self._others)]
        self._noise_std = float(self._spec.noise_std_T) if self._noise and self._spec.noise_std_T > 0 else 0.0
        self._generators = SampleGenerators()
        self.set_name(f"{unit.name}.hall_sensor")
        self.DeclareSeedParameter(seed)

        self._X_port = self.DeclareAbstractInputPort("X_WM", AbstractValue.Make(RigidTransform()))
        self._other_ports = [
            self.DeclareAbstractInputPort(f"X_WM_{o.name}", AbstractValue.Make(RigidTransform()))
            for o in self._others
        ]
        self._B_index = self.DeclareDiscreteState(3)
        self._k_index = self.DeclareDiscreteState(1)
        self._B_port = self.DeclareStateOutputPort("B_sensor_T", self._B_index)
        period = 1.0 / self._spec.sample_rate_hz
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._sample)
        self.DeclareInitializationDiscreteUpdateEvent(self._sample)

    @property
    def spec(self) -> HallSensorSpec:
        return self._spec

    def _magnet_field(self, k: int, unit: MagnetUnitConfig, R_WM: np.ndarray) -> np.ndarray:
        """(3,) field of one unit's magnet at the sensor [T], remembered for the last orientation.

        The field is a function of the orientation alone (the magnet's centre and model are
        fixed), so a magnet that has not turned since the last sample gives the very same value
        without rebuilding its source (the exact model costs about a millisecond a sample).
        """
        key = R_WM.tobytes()
        last = self._last_fields[k]
        if last is None or last[0] != key:
            last = self._last_fields[k] = (key, self._fields[k](R_WM))
        return last[1]

    def true_field(self, context) -> np.ndarray:
        """(3,) noise-free total field at the sensor [T]."""
        X = self._X_port.Eval(context)
        B = self._magnet_field(0, self._unit, X.rotation().matrix()).copy()
        for k, (unit, port) in enumerate(zip(self._others, self._other_ports), start=1):
            B = B + self._magnet_field(k, unit, port.Eval(context).rotation().matrix())
        if self._extra.sources:
            B = B + self._extra.field_and_gradient(self._p_WS)[0][0]
        return B

    def _sample(self, context, discrete_state):
        k = int(context.get_discrete_state().value(self._k_index).item())
        B = self.true_field(context)
        if self._noise_std:
            B = B + self._generators.generator(self.seed(context), k).normal(scale=self._noise_std, size=3)
        discrete_state.set_value(self._B_index, quantise_reading(B, self._spec))
        discrete_state.get_mutable_value(self._k_index)[0] = k + 1

    def get_B_output_port(self):
        return self._B_port


class DipoleDirectionEstimator(LeafSystem):
    """The magnet's dipole direction from one Hall sample (correct inverse of the dipole law).

    Input ports:
        B_sensor_T: (3,) field at the sensor [T].
        X_WM_<name>: RigidTransform (abstract), one per other unit to compensate: its predicted
            field at the sensor (with the other unit's own field model) is subtracted first.

    Output ports:
        m_hat_W: (3,) estimated unit dipole direction in world (zeros while the field is zero,
            i.e. no reading yet).

    ``model="dipole"``: ``m_hat = unit(((3/2) e3 e3^T - I) B)`` (closed form). ``model="exact"``:
    that estimate refined by Gauss-Newton on the exact cylinder field (about 30 ms a sample,
    for offline use). Without compensation, the other magnet of a two-unit station (about 0.5 mT
    at the sensor against 17..34 mT of the own magnet) biases the estimate by up to 2.4 deg.
    """

    def __init__(
        self,
        unit: MagnetUnitConfig,
        *,
        model: str = "dipole",
        compensate_units: Sequence[MagnetUnitConfig] = (),
    ) -> None:
        """
        Args:
            unit: the own unit, placed (magnet, D).
            model: "dipole" or "exact" (see the class docstring).
            compensate_units: other units whose field (point-dipole model) is subtracted;
                their poses come in ports (in the station, their simulated poses: the other
                unit's orientation is assumed known, e.g. from its own sensor).
        """
        super().__init__()
        require_type(unit, MagnetUnitConfig, "DipoleDirectionEstimator unit", "a MagnetUnitConfig")
        if model not in ("dipole", "exact"):
            raise UserInputError(f"estimator model must be 'dipole' or 'exact', got {model!r}")
        self._unit = unit.check_placed()
        self._model = model
        # The other magnets are a third of a metre away, where their dipole field is within
        # about 1 % of the exact one (and 100 times cheaper than magpylib at every evaluation).
        self._others = tuple(replace(o, model="dipole").check_placed() for o in compensate_units)
        self._r = np.array([0.0, 0.0, -unit.sensor_distance])  # magnet centre -> sensor
        self._inversion = FieldInversion(self._r)
        self._p_WS = self._unit.p_WS[None, :]
        self._last_fields: list[tuple[bytes, np.ndarray] | None] = [None] * len(self._others)
        self._fields = [FieldAtPoint(o.magnet, o.p_WM, o.model, unit.p_WS) for o in self._others]
        self._last_estimate: tuple[bytes, np.ndarray] | None = None  # (B.tobytes(), estimate(B))
        self.set_name(f"{unit.name}.estimator")
        self._B_port = self.DeclareVectorInputPort("B_sensor_T", 3)
        self._other_ports = [
            self.DeclareAbstractInputPort(f"X_WM_{o.name}", AbstractValue.Make(RigidTransform()))
            for o in self._others
        ]
        self._m_port = self.DeclareVectorOutputPort("m_hat_W", 3, self._calc,
                                                    prerequisites_of_calc={self.all_input_ports_ticket()})

    def estimate(self, B: np.ndarray) -> np.ndarray:
        """(3,) unit direction from a field sample (3,) [T] of the own magnet; zeros for a zero field."""
        B = np.asarray(B, dtype=float)
        if not B.any():
            return np.zeros(3)
        m = self._inversion.direction(B)
        if self._model == "exact":
            p_S = np.array([[0.0, 0.0, -self._unit.sensor_distance]])

            def model(m_hat):
                return MagnetSource.pointing(self._unit.magnet, np.zeros(3), m_hat, "exact").field(p_S)[0]

            m = refine_direction(B, model, m)
        return m

    def _other_field(self, k: int, R_WM: np.ndarray) -> np.ndarray:
        """(3,) predicted field of compensated unit k at the sensor [T], remembered for its last
        orientation (as ``HallSensor._magnet_field``: a function of the orientation alone)."""
        key = R_WM.tobytes()
        last = self._last_fields[k]
        if last is None or last[0] != key:
            last = self._last_fields[k] = (key, self._fields[k](R_WM))
        return last[1]

    def _estimate_of(self, B: np.ndarray) -> np.ndarray:
        """``estimate(B)``, remembered for the last field (the controller asks at every drive
        update, the sensor samples at half that rate). The array returned is shared: read it."""
        key = B.tobytes()
        last = self._last_estimate
        if last is None or last[0] != key:
            last = self._last_estimate = (key, self.estimate(B))
        return last[1]

    def _calc(self, context, output):
        B = self._B_port.Eval(context)
        if B.any():
            for k, port in enumerate(self._other_ports):
                B = B - self._other_field(k, port.Eval(context).rotation().matrix())
        output.SetFromVector(self._estimate_of(B))
