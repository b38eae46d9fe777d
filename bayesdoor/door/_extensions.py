"""Model extensions of the reduced door: the discrepancy catalogue as code (``docs/model.md``).

Each extension is a frozen module whose fields are static configuration (which sensor, which
wheel, 50 or 60 Hz); its fitted quantities are :class:`~bayesdoor.systems.ParameterSpec` s
named ``"<catalogue name>.<quantity>"`` (``"frame_mode.frequency_hz"``), so they never clash
with the paper's Table 2 names and say which extension they belong to. Every extension is
inert at its nominal values (an amplitude, fraction or participation of zero), so an extended
door at its nominal parameters is the base door.

Two kinds:

- *surface* extensions (``wheel_eccentricity``, ``rail_waviness``) change the height of the
  running surface under a wheel inside the equations of motion: they need a new solve;
- *output* extensions (``frame_mode``, ``sensor_cross_axis``, ``mains_hum``) act on the
  simulated sensor signals only, so they can be applied to, and refitted on, signals already
  simulated (:meth:`ElevatorDoor.apply_output_extensions`);
- extensions with their own *coordinates* (``n_dof``: :class:`CoupledFrameMode`, a frame
  mode that carries the rail) add equations of motion coupled to the door's through the
  wheel contact: they need a new solve.

The rig's effects (``bayesdoor.door.rig``) are the separate higher-fidelity counterparts used to
make test data; these are the reduced model's own, simpler and differentiable, versions.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import ModuleType
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._types import Array, Float
from ..systems import (
    AbstractExtension,
    ParameterSpec,
    UnsynchronisedLines,
    build_extension,
)
from . import _geometry as g

#: the door's two accelerometers and wheels (static choices of the extensions)
SENSORS = ("A1", "A2")
WHEELS = ("left", "right")
#: mains frequencies, Hz
MAINS_FREQUENCIES_HZ = (50.0, 60.0)


def _spec(
    owner: str, quantity: str, unit: str, nominal: float, lower: float, upper: float, text: str
) -> ParameterSpec:
    return ParameterSpec(f"{owner}.{quantity}", unit, nominal, lower, upper, text)


def _mode_specs(
    owner: str, frequency_text: str, participation_text: str
) -> tuple[ParameterSpec, ParameterSpec, tuple[ParameterSpec, ...]]:
    """A mode's frequency (10-300 Hz), damping ratio (0.005-0.1) and the participation of
    every channel (-1 to 1, 0 is off; ``participation_text`` formatted with the channel)."""
    return (
        _spec(owner, "frequency_hz", "Hz", 55.0, 10.0, 300.0, frequency_text),
        _spec(owner, "damping_ratio", "-", 0.02, 0.005, 0.1, "damping ratio of the mode"),
        tuple(
            _spec(owner, f"participation_{c}", "-", 0.0, -1.0, 1.0, participation_text.format(c))
            for c in g.CHANNELS
        ),
    )


class AbstractDoorExtension(AbstractExtension):
    """One model extension of the door (:class:`bayesdoor.systems.AbstractExtension`).

    Concrete extensions implement either :meth:`surface` (they act inside the solve,
    ``needs_resolve = True``) or :meth:`apply` (they act on the sensor signals; ``stage``
    orders them: structure, then sensor, then measurement chain).
    """

    def surface(
        self,
        zeta: Float[Array, ""],
        wheel: int,
        values: Mapping[str, Float[Array, ""]],
        xp: ModuleType = jnp,
    ) -> tuple[Float[Array, ""], Float[Array, ""]] | None:
        """Extra running-surface height under ``wheel`` at rail coordinate ``zeta``, and d/dzeta.

        A positive height pushes the wheel up (it adds to the contact's indentation). ``None``
        when this extension does not touch that wheel (or acts on outputs only).
        """
        return None

    #: coordinates this extension adds to the door's equations of motion (each with its
    #: velocity in the state); they act through :meth:`wheel_lift`, :meth:`dof_accelerations`
    #: and :meth:`sensor_accelerations`
    n_dof: ClassVar[int] = 0

    def wheel_lift(
        self, x: Float[Array, " dof"], values: Mapping[str, Float[Array, ""]], xp=jnp
    ) -> Float[Array, ""]:
        """Rise of the rail under both wheels for the extension's coordinates ``x`` (m)."""
        return 0.0 * xp.sum(x)

    def dof_accelerations(
        self,
        x: Float[Array, " dof"],
        v: Float[Array, " dof"],
        wheel_load: Float[Array, ""],
        values: Mapping[str, Float[Array, ""]],
        xp=jnp,
    ) -> Float[Array, " dof"]:
        """Accelerations of the extension's coordinates, given the wheels' dynamic load (N)."""
        return 0.0 * x

    def sensor_accelerations(
        self, a: Float[Array, " dof"], values: Mapping[str, Float[Array, ""]], xp=jnp
    ) -> Float[Array, " 4"]:
        """What the four channels read of the extension's accelerations ``a`` (m/s^2)."""
        return xp.zeros(len(g.CHANNELS), dtype=a.dtype)


class FrameMode(AbstractDoorExtension):
    """A structural resonance the model lacks (``frame_mode``), as a base-excited mode.

    A single-degree-of-freedom oscillator of frequency f and damping ratio zeta is driven
    by the sum of the base model's accelerations on the ``drive`` channels, d(t):
    u'' + 2 zeta w u' + w^2 u = -d(t) with w = 2 pi f, starting at rest. Its relative
    acceleration u'', transfer function (2 pi nu)^2 / (w^2 - (2 pi nu)^2 + 2 i zeta w 2 pi nu),
    is added to every channel c times a participation p_c. The reduced model's own motion
    excites it, so it rings while the door moves and decays at rest with time constant
    1 / (zeta w); its peak sits at f whatever the door speed, with half-power bandwidth
    2 zeta f. The response to the sampled drive is exact for a drive linear between samples
    (first-order hold, the discretisation of ``scipy.signal.lsim``).

    Parameters (full names ``frame_mode.*``): ``frequency_hz`` (10-300 Hz, the catalogue's
    band), ``damping_ratio`` (0.005-0.1), ``participation_<channel>`` (-1 to 1; 0 is off).
    """

    name: ClassVar[str] = "frame_mode"
    needs_resolve: ClassVar[bool] = False
    stage: ClassVar[int] = 1

    drive: tuple[str, ...] = eqx.field(static=True, default=g.CHANNELS)

    def __check_init__(self):
        unknown = [c for c in self.drive if c not in g.CHANNELS]
        if not self.drive or unknown:
            raise ValueError(
                f"FrameMode.drive={self.drive!r} must name one or more of the door's channels "
                f"{g.CHANNELS}"
            )

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        frequency, damping, participations = _mode_specs(
            self.name,
            "natural frequency of the missing structural mode",
            "share of the mode's relative acceleration seen on {}",
        )
        return (frequency, damping, *participations)

    def response(
        self,
        drive: Float[Array, " time"],
        dt: Float[Array, ""] | float,
        frequency_hz: Float[Array, ""] | float,
        damping_ratio: Float[Array, ""] | float,
    ) -> Float[Array, " time"]:
        """Relative acceleration u'' of the mode driven by the base acceleration ``drive``.

        Exact discretisation for a drive linear between samples: the state (u, u') moves by
        the matrix exponential of the augmented system (C. F. Van Loan (1978), Computing
        integrals involving the matrix exponential, IEEE Trans. Autom. Control 23(3)).
        """
        dtype = drive.dtype
        w = 2.0 * np.pi * jnp.asarray(frequency_hz, dtype)
        zeta = jnp.asarray(damping_ratio, dtype)
        dt = jnp.asarray(dt, dtype)
        zero, one = jnp.zeros((), dtype), jnp.ones((), dtype)
        augmented = jnp.stack(
            [
                jnp.stack([zero, dt, zero, zero]),
                jnp.stack([-(w**2) * dt, -2.0 * zeta * w * dt, -dt, zero]),
                jnp.stack([zero, zero, zero, one]),
                jnp.stack([zero, zero, zero, zero]),
            ]
        )
        e = jax.scipy.linalg.expm(augmented)
        transition = e[:2, :2]
        from_next = e[:2, 3]
        from_this = e[:2, 2] - from_next
        readout = jnp.stack([-(w**2), -2.0 * zeta * w])
        following = jnp.concatenate([drive[1:], drive[-1:]])

        def step(x, d):
            d_this, d_next = d
            y = readout @ x - d_this
            return transition @ x + from_this * d_this + from_next * d_next, y

        _, out = jax.lax.scan(step, jnp.zeros(2, dtype), (drive, following))
        return out

    def apply(self, signals, time, values):
        v = self.local(values)
        drive_rows = np.asarray([g.CHANNELS.index(c) for c in self.drive])
        drive = jnp.sum(signals[drive_rows], axis=0)
        u = self.response(drive, time[1] - time[0], v["frequency_hz"], v["damping_ratio"])
        p = jnp.stack([jnp.asarray(v[f"participation_{c}"], signals.dtype) for c in g.CHANNELS])
        return signals + p[:, None] * u[None, :]


class CoupledFrameMode(AbstractDoorExtension):
    """A structural mode of the frame that carries the rail (``frame_mode``, solved with the door).

    A modal coordinate p (modal mass m_p = 20 kg, the frame's) of frequency f and damping
    ratio zeta lifts the rail under both wheels by ``rail_lift`` lambda per unit p. Its
    generalised force is that of the wheel contacts through the lift, so the wheels'
    vertical load drives it and its lift feeds back into the contacts:
    m_p (p'' + 2 zeta w p' + w^2 p) = -lambda (F_L + F_R - m g), w = 2 pi f, with p measured
    from its static sag under the door's weight m g (the sag only lowers the panel's rest
    height, which no sensor reads). Channel c reads ``participation_c`` times p''. Where
    :class:`FrameMode` is excited by the base model's horizontal accelerations and leaves the
    door unchanged, this mode is excited by the vertical wheel forces, as a frame mode under
    the rail is, and with a strong lift it shifts the door's own modes. It rings while the door
    moves and decays at rest; the peak sits near f whatever the door speed (the coupling moves
    it slightly: the *installed* frequency depends on lambda and the contact stiffness).

    Parameters (full names ``frame_mode.*``): ``frequency_hz`` (10-300 Hz, of the bare mode),
    ``damping_ratio`` (0.005-0.1), ``rail_lift`` (0-0.3; 0 is off),
    ``participation_<channel>`` (-1 to 1).
    """

    name: ClassVar[str] = "frame_mode"
    needs_resolve: ClassVar[bool] = True
    n_dof: ClassVar[int] = 1

    #: what drives the mode (a configuration that reads apart from :class:`FrameMode`'s)
    coupling: str = eqx.field(static=True, default="wheel_contact")

    def __check_init__(self):
        if self.coupling != "wheel_contact":
            raise ValueError(
                f"CoupledFrameMode.coupling={self.coupling!r}: the only coupling is "
                "'wheel_contact' (use FrameMode for a mode driven by the channels)"
            )

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        frequency, damping, participations = _mode_specs(
            self.name,
            "natural frequency of the bare mode (before its coupling to the door)",
            "share of the mode's acceleration seen on {}",
        )
        lift = _spec(
            self.name,
            "rail_lift",
            "-",
            0.0,
            0.0,
            0.3,
            "rise of the rail under the wheels per unit modal displacement",
        )
        return (frequency, damping, lift, *participations)

    def wheel_lift(self, x, values, xp=jnp):
        return self.local(values)["rail_lift"] * x[0]

    def dof_accelerations(self, x, v, wheel_load, values, xp=jnp):
        p = self.local(values)
        w = 2.0 * np.pi * p["frequency_hz"]
        acc = (
            -(w**2) * x[0]
            - 2.0 * p["damping_ratio"] * w * v[0]
            - p["rail_lift"] * wheel_load / g.FRAME_MODAL_MASS
        )
        return xp.stack([acc])

    def sensor_accelerations(self, a, values, xp=jnp):
        p = self.local(values)
        return xp.stack([p[f"participation_{c}"] * a[0] for c in g.CHANNELS])


class SensorCrossAxis(AbstractDoorExtension):
    """Cross-axis sensitivity or misalignment of one accelerometer (``sensor_cross_axis``).

    The ``into`` channel (``"X"`` or ``"Z"``) of ``sensor`` reads its own axis plus
    ``fraction`` times the sensor's other axis (a misalignment by a small angle a gives
    fraction = sin a). Signature: coherence between that sensor's X and Z channels.

    Parameter: ``sensor_cross_axis.fraction`` (-0.3 to 0.3; 0 is off).
    """

    name: ClassVar[str] = "sensor_cross_axis"
    needs_resolve: ClassVar[bool] = False
    stage: ClassVar[int] = 2

    sensor: str = eqx.field(static=True, default="A1")
    into: str = eqx.field(static=True, default="X")

    def __check_init__(self):
        if self.sensor not in SENSORS:
            raise ValueError(f"SensorCrossAxis.sensor={self.sensor!r}: choose one of {SENSORS}")
        if self.into not in ("X", "Z"):
            raise ValueError(f"SensorCrossAxis.into={self.into!r}: choose 'X' or 'Z'")

    @property
    def channels(self) -> tuple[str, str]:
        """(receiving channel, source channel), e.g. ``("A1X", "A1Z")``."""
        other = "Z" if self.into == "X" else "X"
        return f"{self.sensor}{self.into}", f"{self.sensor}{other}"

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        receiving, source = self.channels
        return (
            _spec(
                self.name,
                "fraction",
                "-",
                0.0,
                -0.3,
                0.3,
                f"fraction of {source} read by {receiving}",
            ),
        )

    def apply(self, signals, time, values):
        fraction = jnp.asarray(self.local(values)["fraction"], signals.dtype)
        receiving, source = (g.CHANNELS.index(c) for c in self.channels)
        return signals.at[receiving].add(fraction * signals[source])


class MainsHum(UnsynchronisedLines, AbstractDoorExtension):
    """Electrical interference in the measurement chain (``mains_hum``).

    Channel c receives a_c (cos(2 pi f t + phi_c1) + sum over h = 2..H of r_h cos(2 pi h f t +
    phi_ch)) with f = ``frequency_hz`` (50 or 60 Hz) and H = ``harmonics``: lines at exactly f
    and its harmonics, of constant amplitude, present at rest as while moving.

    The mains is not synchronised with the machine, so a measured record holds the hum at a
    phase of chance against the machine's own content at the same frequency: where that
    content is strong (a door's line near 50 Hz at one speed), the measured change ranges
    from a cancellation to a doubling with the phase (``results/hum_interference.md``). The
    model holds the expectation over the phase: each line's phase ``phi_ch`` puts it in
    quadrature with the channel's signal over the record (their inner product is zero), so
    its power adds to the signal's, as a hum's does on average, instead of interfering with
    one fixed phase. Where the signal holds nothing at the line's frequency the phase does
    not matter.

    Parameters: ``mains_hum.amplitude_<channel>`` (0-0.1 m/s^2, the fundamental's amplitude;
    0 is off) and ``mains_hum.ratio_<h>`` (0-1) for h = 2..H.
    """

    name: ClassVar[str] = "mains_hum"
    needs_resolve: ClassVar[bool] = False
    stage: ClassVar[int] = 3
    supply_frequencies_hz: ClassVar[tuple[float, ...]] = MAINS_FREQUENCIES_HZ
    supply: ClassVar[str] = "mains"
    sampling_rate_hz: ClassVar[float] = g.SAMPLING_RATE_HZ

    frequency_hz: float = eqx.field(static=True, default=50.0)
    harmonics: int = eqx.field(static=True, default=3)

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        return (
            *(
                _spec(
                    self.name,
                    f"amplitude_{c}",
                    "m/s^2",
                    0.0,
                    0.0,
                    0.1,
                    f"amplitude of the {self.frequency_hz:g} Hz line on {c}",
                )
                for c in g.CHANNELS
            ),
            *(
                _spec(
                    self.name,
                    f"ratio_{h}",
                    "-",
                    0.0,
                    0.0,
                    1.0,
                    f"amplitude of harmonic {h} relative to the fundamental",
                )
                for h in range(2, self.harmonics + 1)
            ),
        )

    def weigh(self, units, values, dtype):
        """Each channel's amplitude times the fundamental plus the harmonics at their
        ratios."""
        line = units[0]
        for h in range(2, self.harmonics + 1):
            line = line + jnp.asarray(values[f"ratio_{h}"], dtype) * units[h - 1]
        a = jnp.stack([jnp.asarray(values[f"amplitude_{c}"], dtype) for c in g.CHANNELS])
        return a[:, None] * line


class WheelEccentricity(AbstractDoorExtension):
    """An out-of-round wheel (``wheel_eccentricity``): needs a new solve.

    The radius of ``wheel`` varies with its rolling angle alpha = zeta / R as
    sum over k = 1..H of a_k cos(k alpha + phi_k), H = ``harmonics``; rolling without slip
    this enters the wheel-rail gap like a rail height and excites tones at k v / (2 pi R),
    the wheel's rotation frequency and its harmonics, tracking the door speed.

    Parameters: ``wheel_eccentricity.amplitude_<k>`` (0-50 um; 0 is off) and
    ``wheel_eccentricity.phase_<k>`` (0 to 2 pi rad) for k = 1..H.
    """

    name: ClassVar[str] = "wheel_eccentricity"
    needs_resolve: ClassVar[bool] = True

    wheel: str = eqx.field(static=True, default="right")
    harmonics: int = eqx.field(static=True, default=1)

    def __check_init__(self):
        if self.wheel not in WHEELS:
            raise ValueError(f"WheelEccentricity.wheel={self.wheel!r}: choose one of {WHEELS}")
        if not 1 <= self.harmonics <= 8:
            raise ValueError(
                f"WheelEccentricity.harmonics={self.harmonics!r} must be between 1 and 8"
            )

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        specs = []
        for k in range(1, self.harmonics + 1):
            specs.append(
                _spec(
                    self.name,
                    f"amplitude_{k}",
                    "m",
                    0.0,
                    0.0,
                    50e-6,
                    f"radius amplitude of harmonic {k} of the {self.wheel} wheel",
                )
            )
            specs.append(
                _spec(
                    self.name,
                    f"phase_{k}",
                    "rad",
                    np.pi,
                    0.0,
                    2.0 * np.pi,
                    f"phase of harmonic {k} at the closed position",
                )
            )
        return tuple(specs)

    def surface(self, zeta, wheel, values, xp=jnp):
        if WHEELS[wheel] != self.wheel:
            return None
        v = self.local(values)
        alpha = zeta / g.WHEEL_RADIUS
        height, slope = 0.0 * zeta, 0.0 * zeta
        for k in range(1, self.harmonics + 1):
            arg = k * alpha + v[f"phase_{k}"]
            a = v[f"amplitude_{k}"]
            height = height + a * xp.cos(arg)
            slope = slope - a * (k / g.WHEEL_RADIUS) * xp.sin(arg)
        return height, slope


class RailWaviness(AbstractDoorExtension):
    """A periodic rail irregularity of one wavelength (``rail_waviness``): needs a new solve.

    Adds a sin(2 pi zeta / lambda + ``phase``) to the rail height under both wheels, on top
    of the door's built-in waviness; it excites a tone at v / lambda, tracking the door speed.
    The phase is static (spectral features barely see it: it only shifts the relative phase
    of the two wheels' excitations, which their 0.7 m spacing fixes anyway).

    With ``independent=True`` each wheel meets the irregularity at its own phase: under wheel
    w it adds s_w sin(2 pi zeta / lambda) + c_w cos(2 pi zeta / lambda), four parameters
    linear in the height. A real rail is not periodic over the wheels' 0.7 m to a fraction
    of a wavelength, and a wavelength estimated 1 % off turns the two wheels' relative phase
    by 0.7 m / lambda hundredths of a cycle (a fifth of a cycle at 35 mm); with the phases
    free the tone's level no longer hinges on that.

    Parameters: ``rail_waviness.wavelength_m`` (4-200 mm) and ``rail_waviness.amplitude_m``
    (0-30 um; 0 is off); with ``independent``, also ``rail_waviness.sin_left_m``,
    ``cos_left_m``, ``sin_right_m`` and ``cos_right_m`` (-30 to 30 um; 0 is off).
    """

    name: ClassVar[str] = "rail_waviness"
    needs_resolve: ClassVar[bool] = True

    phase: float = eqx.field(static=True, default=0.0)
    independent: bool = eqx.field(static=True, default=False)

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        specs = (
            _spec(
                self.name,
                "wavelength_m",
                "m",
                0.02,
                4e-3,
                0.2,
                "wavelength of the rail irregularity",
            ),
            _spec(
                self.name,
                "amplitude_m",
                "m",
                0.0,
                0.0,
                30e-6,
                "amplitude of the rail irregularity",
            ),
        )
        if not self.independent:
            return specs
        parts = tuple(
            _spec(
                self.name,
                f"{part}_{wheel}_m",
                "m",
                0.0,
                -30e-6,
                30e-6,
                f"{part} part of the irregularity under the {wheel} wheel",
            )
            for wheel in WHEELS
            for part in ("sin", "cos")
        )
        return specs + parts

    def surface(self, zeta, wheel, values, xp=jnp):
        v = self.local(values)
        k = 2.0 * np.pi / v["wavelength_m"]
        arg = k * zeta + self.phase
        height = v["amplitude_m"] * xp.sin(arg)
        slope = v["amplitude_m"] * k * xp.cos(arg)
        if self.independent:
            s, c = v[f"sin_{WHEELS[wheel]}_m"], v[f"cos_{WHEELS[wheel]}_m"]
            sin, cos = xp.sin(k * zeta), xp.cos(k * zeta)
            height = height + s * sin + c * cos
            slope = slope + k * (s * cos - c * sin)
        return height, slope


#: the extension class of every catalogue name (``none`` is the base model: no class)
EXTENSIONS: dict[str, type[AbstractDoorExtension]] = {
    cls.name: cls for cls in (FrameMode, WheelEccentricity, RailWaviness, SensorCrossAxis, MainsHum)
}


def extension(name_or_module: str | AbstractDoorExtension, **config) -> AbstractDoorExtension:
    """The extension of a catalogue name (default configuration, or ``config``), or the module.

    Raises
    ------
    ValueError
        For a name outside the catalogue, or ``"none"`` (the base model has no extension).

    Examples
    --------
    >>> extension("mains_hum", frequency_hz=60.0)
    MainsHum(frequency_hz=60.0)
    """
    return build_extension(name_or_module, EXTENSIONS, "the door", **config)
