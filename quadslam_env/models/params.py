"""Vehicle parameters and presets (docs/design.md §3; seed 001 Table 1, seed 000 §IV; the
Crazyflie 2.0 of Förster 2015, see :mod:`quadslam_env.models.rotors`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from quadslam_env.models.rotors import CRAZYFLIE2_ROTORS, RotorParams
from quadslam_env.types import GRAVITY, FloatArray


@dataclass(frozen=True)
class VehicleParams:
    """Physical parameters of a quadcopter.

    Attributes:
        name: Preset name or ``"custom"``.
        mass: Mass m in kg.
        inertia: (3, 3) inertia matrix J in kg·m² (body frame).
        max_thrust: Upper thrust limit in N (the lower limit is 0).
        max_torque: (3,) symmetric torque limits in N·m per body axis.
        drag: Linear drag coefficient in 1/s (``v̇ += -drag · v``); 0 disables it.
        actuator_tau: First-order actuator time constant in s; 0 disables the lag.
        drag_quadratic: (3,) quadratic drag coefficients c_q per body axis in 1/m (specific
            force ``−c_q ∘ (‖v_a‖ v_a)`` on the air-relative velocity v_a); zeros disable it.
            The simulator's truth only: the estimators' process models leave it out, except a
            model with drag told the wind (``wind.inform_estimator``).
        rotors: The rotor model (:class:`~quadslam_env.models.rotors.RotorParams`), or
            ``None``: thrust and torque act directly (through ``actuator_tau``). With rotors,
            ``max_thrust`` and ``max_torque`` are the rotors' (all at full speed; half at the
            top and half at the bottom of their range: the scale of the normalised action; what
            an attitude loop gets around hover is :attr:`hover_torque`) and ``actuator_tau`` is
            0 (the motor lag is the rotors').
        inertia_inv: (3, 3) ``J⁻¹`` in 1/(kg·m²), derived.
    """

    name: str
    mass: float
    inertia: FloatArray
    max_thrust: float
    max_torque: FloatArray
    drag: float = 0.0
    actuator_tau: float = 0.0
    drag_quadratic: FloatArray = field(default_factory=lambda: np.zeros(3))
    rotors: RotorParams | None = None
    inertia_inv: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        inertia = np.array(self.inertia, dtype=float).reshape(3, 3)
        inertia.setflags(write=False)
        torque = np.array(self.max_torque, dtype=float).reshape(3)
        torque.setflags(write=False)
        inv = np.linalg.inv(inertia)
        inv.setflags(write=False)
        object.__setattr__(self, "inertia", inertia)
        object.__setattr__(self, "max_torque", torque)
        quadratic = np.array(self.drag_quadratic, dtype=float).reshape(3)
        quadratic.setflags(write=False)
        object.__setattr__(self, "drag_quadratic", quadratic)
        object.__setattr__(self, "inertia_inv", inv)

    @property
    def hover_thrust(self) -> float:
        """Thrust that balances gravity, ``m g`` in N."""
        return self.mass * GRAVITY

    @property
    def hover_torque(self) -> FloatArray:
        """(3,) torque per body axis in N·m available while the thrust balances gravity.

        Without rotors the thrust and the torques saturate independently, so it is
        ``max_torque``; with rotors they share the rotors' range and it is
        :meth:`RotorParams.hover_torque` of ``m g``, less than ``max_torque`` wherever the
        hover thrust is not half-way up the rotors' range (the yaw torque of the inverse mixer
        gives way first, :func:`~quadslam_env.models.rotors.allocate`).
        """
        if self.rotors is None:
            return self.max_torque
        return self.rotors.hover_torque(self.hover_thrust)


def _preset(
    name: str,
    mass: float,
    inertia_diag: tuple[float, float, float],
    torque: float,
    yaw_torque: float,
) -> VehicleParams:
    # Thrust limit 2.5 m g: a typical thrust-to-weight ratio for research quadcopters.
    return VehicleParams(
        name=name,
        mass=mass,
        inertia=np.diag(inertia_diag),
        max_thrust=2.5 * mass * GRAVITY,
        max_torque=np.array([torque, torque, yaw_torque]),
    )


def rotor_vehicle(
    name: str,
    mass: float,
    inertia: FloatArray,
    rotors: RotorParams,
    drag: float = 0.0,
    drag_quadratic: FloatArray | None = None,
) -> VehicleParams:
    """A vehicle with rotors: its thrust and torque limits are the rotors'
    (:attr:`RotorParams.max_collective_thrust`, :attr:`RotorParams.max_torque`).

    Args:
        name: Preset name. mass: kg. inertia: (3, 3) kg·m² in B. rotors: The rotor model.
        drag: Linear drag in 1/s. drag_quadratic: (3,) in 1/m, or ``None`` (zeros).
    """
    return VehicleParams(
        name=name,
        mass=mass,
        inertia=inertia,
        max_thrust=rotors.max_collective_thrust,
        max_torque=rotors.max_torque,
        drag=drag,
        drag_quadratic=np.zeros(3) if drag_quadratic is None else drag_quadratic,
        rotors=rotors,
    )


VEHICLE_PRESETS: dict[str, VehicleParams] = {
    # Seed 001 Table 1. Torque limits: ~0.25 m arm with a quarter of the thrust margin.
    "rauniyar2023": _preset("rauniyar2023", 1.56, (0.1147, 0.0576, 0.1712), 2.0, 1.0),
    # Seed 000 §IV (Hector quadrotor): smaller inertia, so smaller torque limits.
    "sadeghzadeh2021": _preset("sadeghzadeh2021", 1.477, (0.01152, 0.01152, 0.0218), 0.5, 0.25),
    # Förster 2015 (ETH Zürich BSc thesis), Crazyflie 2.0: 27 g, inertia Table of the thesis,
    # rotors of quadslam_env.models.rotors (thrust-to-weight 2.25).
    "crazyflie2": rotor_vehicle(
        "crazyflie2", 0.027, np.diag([1.395e-5, 1.436e-5, 2.173e-5]), CRAZYFLIE2_ROTORS
    ),
}


def vehicle_preset(name: str) -> VehicleParams:
    """Return the vehicle preset ``name`` (``rauniyar2023``, ``sadeghzadeh2021``, ``crazyflie2``).

    Raises:
        ValueError: If the name is unknown; the message lists the allowed names.
    """
    try:
        return VEHICLE_PRESETS[name]
    except KeyError:
        raise ValueError(
            f"vehicle.preset: unknown preset {name!r}; allowed: {sorted(VEHICLE_PRESETS)}"
        ) from None
