"""Per-joint servo drives: a DC motor through a gear under a cascaded position / velocity loop.

Each joint is an independent drive (no gravity, no coupling between joints), in joint-side
units: inertia ``J = rotor_inertia * N^2 + load_inertia``, peak torque ``N * Kt * I_max``, viscous
friction ``b_m * N^2`` and Coulomb friction ``T_c * N`` (N the gear ratio). Every servo period:

* position loop (P): ``w_cmd = Kp (q_cmd - q) + k_ff v_cmd``;
* velocity loop (PI): ``tau = Kv (w_cmd - w) + Kv / Ti * integral(w_cmd - w)``, ``Kv = J x
  bandwidth``; the torque saturates at the peak torque (and the integral stops growing while it
  does, so the loop does not wind up);
* the load: ``J dw/dt = tau - b w - T_c sign(w)``, with static friction holding the joint while
  the torque stays below T_c; integrated semi-implicitly (velocity first, then position).

At a constant commanded speed v the integral removes the velocity error, so the following error
settles at ``(1 - k_ff) v / Kp``.

The loop runs on plain floats, joint by joint: for six joints that is several times faster than
numpy on arrays of six.
"""

from __future__ import annotations

from collections.abc import Sequence

from ..model import MotorParameters

__all__ = ["ServoDrives"]


class ServoDrives:
    """The drives of all joints; ``position``, ``velocity``, ``acceleration`` are the actual state."""

    def __init__(self, motors: Sequence[MotorParameters], period: float, position: Sequence[float]) -> None:
        if not period > 0.0:
            raise ValueError(f"the servo period must be > 0, not {period}")
        self.period = float(period)
        self.motors = tuple(motors)
        self._constants = []
        for m in self.motors:
            n = m.gear_ratio
            inertia = m.rotor_inertia * n * n + m.load_inertia
            kv = inertia * m.velocity_bandwidth
            ki = kv / m.velocity_integral_time if m.velocity_integral_time > 0.0 else 0.0
            self._constants.append(
                (
                    1.0 / inertia,
                    n * m.torque_constant * m.max_current,
                    m.viscous_friction * n * n,
                    m.coulomb_friction * n,
                    m.position_gain,
                    m.velocity_feedforward,
                    kv,
                    ki,
                )
            )
        self.following_error_limit = [m.following_error_limit for m in self.motors]
        self.peak_torque = [c[1] for c in self._constants]
        self.position = [float(p) for p in position]
        self.velocity = [0.0] * len(self.motors)
        self.acceleration = [0.0] * len(self.motors)
        self.torque = [0.0] * len(self.motors)
        self._integral = [0.0] * len(self.motors)
        if len(self.position) != len(self.motors):
            raise ValueError(f"{len(self.position)} positions for {len(self.motors)} drives")

    def step(self, command_position: Sequence[float], command_velocity: Sequence[float]) -> None:
        """Advance one servo period towards the commanded position and velocity."""
        self.follow(command_position, command_position, command_velocity, command_velocity, 1.0)

    def follow(
        self,
        start: Sequence[float],
        end: Sequence[float],
        start_velocity: Sequence[float],
        end_velocity: Sequence[float],
        share: float,
        *,
        increment_period: float | None = None,
    ) -> int:
        """Advance one servo period towards the setpoint ``share`` of the way from ``start`` to
        ``end`` (the linear interpolation between two interpolation instants), its velocity
        interpolated the same way or, with ``increment_period``, the increment's rate ``(end -
        start) / increment_period`` (MotoROS's feed-forward). Returns the first joint whose
        following error (command - actual) is then beyond its limit, -1 if none. (One loop for
        the interpolation, the drives and the check: this runs for every servo tick of every moving
        controller of a fleet.)"""
        f = share
        g = 1.0 - f
        dt = self.period
        position, velocity, integral = self.position, self.velocity, self._integral
        acceleration, torque, limits = self.acceleration, self.torque, self.following_error_limit
        beyond = -1
        for i, (inv_j, peak, viscous, coulomb, kp, kff, kv, ki) in enumerate(self._constants):
            x = start[i]
            y = end[i]
            c = g * x + f * y
            v = g * start_velocity[i] + f * end_velocity[i] if increment_period is None else (y - x) / increment_period
            q, w = position[i], velocity[i]
            error = kp * (c - q) + kff * v - w
            tau = kv * error + ki * integral[i]
            if tau > peak:
                tau = peak
            elif tau < -peak:
                tau = -peak
            else:
                integral[i] += error * dt  # conditional integration: no wind-up at saturation
            if w > 0.0:
                drive = tau - viscous * w - coulomb
            elif w < 0.0:
                drive = tau - viscous * w + coulomb
            elif tau > coulomb:
                drive = tau - coulomb
            elif tau < -coulomb:
                drive = tau + coulomb
            else:
                drive = 0.0  # static friction holds
            w_new = w + drive * inv_j * dt
            if (w > 0.0 > w_new or w < 0.0 < w_new) and abs(tau) <= coulomb:
                w_new = 0.0  # friction stops the joint; it cannot reverse it
            acceleration[i] = (w_new - w) / dt
            torque[i] = tau
            velocity[i] = w_new
            position[i] = p = q + w_new * dt
            if beyond < 0 and abs(c - p) > limits[i]:
                beyond = i
        return beyond

    @property
    def integral(self) -> list[float]:
        """The velocity loops' integrals (the drives' state besides position and velocity)."""
        return self._integral

    def hold(self) -> None:
        """Forget the velocity-loop integral (after an abort, when the command jumps to the actual position)."""
        self._integral = [0.0] * len(self.motors)

    def brake(self) -> None:
        """Power removed, holding brakes closed: every joint stands still where it is (an ideal
        brake: a real axis coasts a few milliradians first) and the loops forget their state."""
        n = len(self.motors)
        self.velocity = [0.0] * n
        self.acceleration = [0.0] * n
        self.torque = [0.0] * n
        self._integral = [0.0] * n
