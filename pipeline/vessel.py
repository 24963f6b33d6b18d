"""Vessel configuration: the TOML of DESIGN.md, read into a frozen :class:`Vessel`.

Minimal form is ``name`` alone (a rudder ship whose mass is unknown: only Nomoto is identified).
All sections are optional; unknown keys are errors that name the key and the allowed ones. Every
table, including those later stages read (``[thrusters]``, ``[topics]``, ``[sensors]``), is also
checked against :data:`pipeline.config_schema.VESSEL_SCHEMA` when the file is read, before any work.

Sections
--------
``[rigid_body]``  mass [kg], inertia [Ixx, Iyy, Izz] about the CG [kg m^2], cg [m, body frame].
``[added_mass]``  positive added mass per DOF (surge, sway, roll, pitch, yaw) [kg or kg m^2].
``[restoring]``   roll, pitch [N m/rad].
``[damping]``     ``matrix`` 5x5 D [SI] or ``diagonal`` 5 values, DOF order u v p q r; truth for the
                  simulator and a prior for the fits. ``quadratic`` 5 values [SI] of |x|x damping.
``[nomoto]``      K [1/s], T [s]: the rudder ship's yaw model for the simulator.
``[rudder]``      max_angle [rad], max_rate [rad/s], yaw_moment [N m/rad], sway_force [N/rad].
``[[actuators]]`` map of MAVLink servo / RC channels to canonical inputs (see :class:`ActuatorMap`);
                  maps of one channel are one actuator driving several inputs, optional ``name``
                  (the allocation, :func:`actuator_allocation`).
``[sensor_noise]`` optional: standard deviation of a sensor's white noise per logged sample, by
                  canonical channel, in its SI unit (``psi = 0.002`` rad, ``r = 0.002`` rad/s, ``sog``
                  m/s), from a datasheet or a record at rest. Default: none, and the diagnosis
                  estimates every noise floor from the data. Where given, the diagnosis takes the
                  smaller of the two (:func:`pipeline.diagnose.problem.block_noise`): from the data
                  alone a disturbance a few samples per period (waves on a heading logged at 1-3 Hz)
                  cannot be told from sensor noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .config_schema import VESSEL_SCHEMA, read_toml, validate
from .errors import ConfigError
from .records import DOF_NAMES, DOFS

#: ``[[actuators]]`` sources whose values are normalised to [-1, 1] (PX4 ``actuator_motors`` and
#: ``actuator_servos``) rather than PWM: their neutral is 0 and their span 1 unless given.
NORMALISED_SOURCES = ("motor", "servo_control")


@dataclass(frozen=True)
class ActuatorMap:
    """How one PWM channel maps to a canonical input.

    ``value = full_scale * (pwm - pwm_trim) / pwm_span`` for pwm above trim, and
    ``reverse_scale * (pwm - pwm_trim) / pwm_span`` below it (thrusters are often weaker in reverse).

    Attributes
    ----------
    source : str
        ``servo`` (SERVO_OUTPUT_RAW / RCOU / PX4 actuator_outputs) or ``rc`` (RC_CHANNELS / RCIN), PWM [us];
        ``motor`` (PX4 actuator_motors) or ``servo_control`` (PX4 actuator_servos), normalised [-1, 1].
    channel : int
        1-based channel number.
    target : str
        Canonical input (``delta``, ``tau_x``, ...).
    pwm_trim, pwm_span : float
        Neutral PWM and PWM distance to full scale [us] (for a normalised source, in its units:
        0 and 1 by default).
    full_scale, reverse_scale : float
        Input at ``pwm_trim + pwm_span`` and magnitude at ``pwm_trim - pwm_span`` [SI unit of target];
        ``reverse_scale`` defaults to ``full_scale``.
    name : str or None
        The actuator's name (``thruster_port``); maps of one source and channel are one actuator
        (:func:`actuator_allocation`). None: ``<source><channel>`` (``servo3``).
    """

    source: str
    channel: int
    target: str
    pwm_trim: float = 1500.0
    pwm_span: float = 400.0
    full_scale: float = 1.0
    reverse_scale: float | None = None
    name: str | None = None

    def __post_init__(self) -> None:
        # A symmetric actuator unless told otherwise: reverse scale follows the forward one.
        if self.reverse_scale is None:
            object.__setattr__(self, "reverse_scale", self.full_scale)

    def to_input(self, pwm: np.ndarray) -> np.ndarray:
        """Convert PWM [us] to the target input [SI].

        Parameters
        ----------
        pwm : array_like
            Pulse widths [us]; ``full_scale`` applies above ``pwm_trim``, ``reverse_scale`` below.
        """
        x = (np.asarray(pwm, float) - self.pwm_trim) / self.pwm_span
        return np.where(x >= 0, self.full_scale * x, self.reverse_scale * x)

    def to_pwm(self, value: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_input` [us].

        Parameters
        ----------
        value : array_like
            Target input [SI unit of ``target``]; negative values use ``reverse_scale``.
        """
        v = np.asarray(value, float)
        x = np.where(v >= 0, v / self.full_scale, v / self.reverse_scale)
        return self.pwm_trim + self.pwm_span * x


@dataclass(frozen=True)
class Actuator:
    """One physical actuator and the inputs it drives: a column of the allocation ``tau = B(a)``.

    Its own signal ``a`` is the normalised command ``(pwm - pwm_trim) / pwm_span`` of its
    ``[[actuators]]`` maps (dimensionless, 1 at full scale ahead). Each input it drives receives
    ``gains[input][0] * a`` for ``a >= 0`` and ``gains[input][1] * a`` below (a propeller weaker
    astern), and an input driven by several actuators is their sum, as the log readers add them.

    Attributes
    ----------
    name : str
        The actuator's name (``thruster_port``, or ``servo3`` when the config names none).
    gains : Mapping[str, tuple[float, float]]
        Input channel -> (ahead, astern) gain [SI unit of the input per unit of ``a``].
    """

    name: str
    gains: Mapping[str, tuple[float, float]]

    def contribution(self, channel: str, a: np.ndarray) -> np.ndarray:
        """What the actuator's signal ``a`` adds to input ``channel`` [SI unit of the input].

        Parameters
        ----------
        channel : str
            An input channel it drives (else zeros).
        a : numpy.ndarray
            The actuator's normalised signal [-].
        """
        a = np.asarray(a, float)
        if channel not in self.gains:
            return np.zeros_like(a)
        ahead, astern = self.gains[channel]
        return np.where(a >= 0, ahead * a, astern * a)


def actuator_allocation(actuators: tuple[ActuatorMap, ...], where: str = "[[actuators]]") -> tuple[Actuator, ...]:
    """The allocation the ``[[actuators]]`` maps define: maps of one source and channel are one
    actuator, each map one input it drives (a twin-thruster boat's port thruster: one map to
    ``tau_x``, one to ``tau_n``).

    Parameters
    ----------
    actuators : tuple[ActuatorMap, ...]
        The vessel's maps.
    where : str
        Config file and table, for the message.

    Returns
    -------
    tuple[Actuator, ...]
        In the order of first appearance; ``rc`` maps (pilot inputs) are not actuators and left out.

    Raises
    ------
    ConfigError
        Maps of one actuator with different names, PWM trims or spans, one actuator mapped twice
        to the same input, or one name on two actuators.
    """
    groups: dict[tuple[str, int], list[ActuatorMap]] = {}
    for a in actuators:
        if a.source == "rc":
            continue  # a pilot's stick is a command (logged as ``<input>@rc`` beside the servo's), not an actuator
        groups.setdefault((a.source, a.channel), []).append(a)
    out, owner = [], {}
    for (src, ch), maps in groups.items():
        names = {m.name for m in maps if m.name}
        spans = {(m.pwm_trim, m.pwm_span) for m in maps}
        targets = [m.target for m in maps]
        if len(names) > 1 or len(spans) > 1 or len(set(targets)) < len(targets):
            raise ConfigError(f"{where}: the maps of {src} channel {ch} are one actuator: expected one name, one "
                              f"pwm_trim and pwm_span and each target once, found names {sorted(names)}, "
                              f"(trim, span) {sorted(spans)}, targets {targets}")
        name = names.pop() if names else f"{src}{ch}"
        if name in owner:
            raise ConfigError(f"{where}: expected one actuator per name, found {name!r} on {owner[name]} and "
                              f"{src} channel {ch}")
        owner[name] = f"{src} channel {ch}"
        out.append(Actuator(name, {m.target: (float(m.full_scale), float(m.reverse_scale)) for m in maps}))
    return tuple(out)


@dataclass(frozen=True)
class Vessel:
    """A vessel's known physical data (not the identified coefficients).

    Attributes
    ----------
    name : str
        Vessel name.
    mass : float or None
        Mass [kg]; None for a rudder ship identified by Nomoto only.
    inertia : numpy.ndarray
        Ixx, Iyy, Izz about the CG [kg m^2].
    cg : numpy.ndarray
        Centre of gravity in the body frame [m].
    added_mass : Mapping[str, float]
        Positive added mass per DOF name [kg or kg m^2].
    restoring : Mapping[str, float]
        Restoring stiffness for roll and pitch [N m/rad].
    damping : numpy.ndarray or None
        Linear damping D (5x5, DOF order u v p q r) [SI]; None if not given.
    quadratic_damping : numpy.ndarray or None
        |x|x damping coefficients per DOF [SI]; None if not given.
    nomoto : Mapping[str, float]
        ``K`` [1/s] and ``T`` [s] when given.
    rudder : Mapping[str, float]
        Rudder limits and effectiveness (``max_angle`` [rad], ``max_rate`` [rad/s],
        ``yaw_moment`` [N m/rad], ``sway_force`` [N/rad]).
    actuators : tuple[ActuatorMap, ...]
        PWM channel map for MAVLink / DataFlash logs.
    sensor_noise : Mapping[str, float]
        Stated white-noise standard deviation per logged sample, by canonical channel [SI]; empty
        when not given (the noise is then estimated from the data).
    extra : Mapping[str, Any]
        Sections that later stages read themselves (``thrusters``, ``topics``, ``sensors``).
    path : str
        File it was read from.
    """

    name: str
    mass: float | None = None
    inertia: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    cg: np.ndarray = field(default_factory=lambda: np.zeros(3))
    added_mass: Mapping[str, float] = field(default_factory=dict)
    restoring: Mapping[str, float] = field(default_factory=dict)
    damping: np.ndarray | None = None
    quadratic_damping: np.ndarray | None = None
    nomoto: Mapping[str, float] = field(default_factory=dict)
    rudder: Mapping[str, float] = field(default_factory=dict)
    actuators: tuple[ActuatorMap, ...] = ()
    sensor_noise: Mapping[str, float] = field(default_factory=dict)
    extra: Mapping[str, Any] = field(default_factory=dict)
    path: str = ""

    @property
    def has_rigid_body(self) -> bool:
        """True when mass and inertia are known (the 5-DOF damping matrix can be identified)."""
        return self.mass is not None and bool(np.all(np.isfinite(self.inertia)))

    def rigid_body_mass_matrix(self) -> np.ndarray:
        """M_RB about the body origin for DOFs u, v, p, q, r [SI] (Fossen 2021, eq. 3.44).

        The CG offset couples DOFs (for example m z_g between sway and roll); inertia given about
        the CG is moved to the origin by the parallel-axis theorem.
        """
        if not self.has_rigid_body:
            raise ConfigError(f"{self.name}: rigid_body.mass and rigid_body.inertia are needed for M_RB; found "
                              f"mass={self.mass}, inertia={self.inertia.tolist()}")
        m = float(self.mass)
        xg, yg, zg = (float(c) for c in self.cg)
        ixx, iyy, izz = (float(i) for i in self.inertia)
        # Full 6x6 M_RB with r_g = [xg, yg, zg]; products of inertia neglected.
        m6 = np.array([
            [m, 0, 0, 0, m * zg, -m * yg],
            [0, m, 0, -m * zg, 0, m * xg],
            [0, 0, m, m * yg, -m * xg, 0],
            [0, -m * zg, m * yg, ixx + m * (yg**2 + zg**2), -m * xg * yg, -m * xg * zg],
            [m * zg, 0, -m * xg, -m * xg * yg, iyy + m * (xg**2 + zg**2), -m * yg * zg],
            [-m * yg, m * xg, 0, -m * xg * zg, -m * yg * zg, izz + m * (xg**2 + yg**2)],
        ])
        keep = [0, 1, 3, 4, 5]  # drop heave: u, v, p, q, r
        return m6[np.ix_(keep, keep)]

    def added_mass_matrix(self) -> np.ndarray:
        """M_A, diagonal, DOF order u v p q r [SI] (zero where not given)."""
        return np.diag([float(self.added_mass.get(DOF_NAMES[d], 0.0)) for d in DOFS])

    def mass_matrix(self) -> np.ndarray:
        """M = M_RB + M_A for DOFs u, v, p, q, r [SI]."""
        return self.rigid_body_mass_matrix() + self.added_mass_matrix()

    def effective_mass(self, dof: str) -> float:
        """Diagonal M[i, i] for one DOF name (surge ... yaw) [kg or kg m^2].

        This is the single-DOF inertia a first-order fit uses: T = M[i, i] / D[i, i].

        Parameters
        ----------
        dof : str
            DOF name (``surge``, ``sway``, ``roll``, ``pitch``, ``yaw``) or its velocity
            (``u``, ``v``, ``p``, ``q``, ``r``).

        Raises
        ------
        ConfigError
            Unknown DOF, or mass and inertia not given.
        """
        i = DOFS.index(_velocity_of(dof))
        return float(self.mass_matrix()[i, i])

    def restoring_matrix(self) -> np.ndarray:
        """G: diagonal restoring on (phi, theta) placed in DOF order u v p q r [SI]."""
        g = np.zeros((5, 5))
        g[2, 2] = float(self.restoring.get("roll", 0.0))
        g[3, 3] = float(self.restoring.get("pitch", 0.0))
        return g


def _velocity_of(dof: str) -> str:
    for vel, name in DOF_NAMES.items():
        if name == dof or vel == dof:
            return vel
    raise ConfigError(f"unknown DOF {dof!r}; expected one of {list(DOF_NAMES.values())}")


def _check_positive_definite(where: str, D: np.ndarray) -> None:
    """Raise ConfigError unless ``D`` is positive definite (its symmetric part has eigenvalues > 0).

    A damping matrix with a zero or negative eigenvalue makes a vessel that gains energy from the
    water: usually a derivative entered with Fossen's negative sign (``X_u``) instead of ``D = -X_u``.

    Parameters
    ----------
    where : str
        Config file and table, for the message.
    D : numpy.ndarray
        5x5 damping matrix, DOF order u v p q r [SI].
    """
    eig = np.linalg.eigvalsh(0.5 * (D + D.T))
    if eig.min() <= 0.0:
        diag = ", ".join(f"{x:.6g}" for x in np.diag(D))
        raise ConfigError(f"{where}: expected a positive definite damping matrix D (M nu_dot + D nu = tau, "
                          f"D = -derivative, so the diagonal is positive), found smallest eigenvalue "
                          f"{eig.min():.6g} (diagonal {diag}); enter D, not Fossen's negative derivatives")


def parse_vessel(doc: Mapping[str, Any], path: str = "<dict>") -> Vessel:
    """Build a :class:`Vessel` from a parsed TOML document.

    Every table is checked first by the one schema (:data:`pipeline.config_schema.VESSEL_SCHEMA`:
    key names, types, lengths, signs, allowed words; every problem listed at once); what remains
    here is what a schema cannot say: mass and inertia given together, one damping form, and a
    positive definite damping matrix.

    Parameters
    ----------
    doc : Mapping
        Parsed TOML.
    path : str
        Where it came from, for error messages.

    Raises
    ------
    ConfigError
        Unknown keys, wrong types, missing ``name``, inconsistent tables.
    """
    validate(doc, VESSEL_SCHEMA, path)
    kw: dict[str, Any] = {"name": doc["name"], "path": path}

    rb = doc.get("rigid_body", {})
    if ("mass" in rb) != ("inertia" in rb):
        raise ConfigError(f"{path} [rigid_body]: expected both mass and inertia, found only {sorted(rb)}")
    if "mass" in rb:
        kw["mass"] = float(rb["mass"])
        kw["inertia"] = np.asarray(rb["inertia"], float)
    if "cg" in rb:
        kw["cg"] = np.asarray(rb["cg"], float)
    kw["added_mass"] = {k: float(v) for k, v in doc.get("added_mass", {}).items()}
    kw["restoring"] = {k: float(v) for k, v in doc.get("restoring", {}).items()}

    dmp = doc.get("damping", {})
    if "matrix" in dmp and "diagonal" in dmp:
        raise ConfigError(f"{path} [damping]: give either matrix or diagonal, found both")
    if "matrix" in dmp:
        kw["damping"] = np.asarray(dmp["matrix"], float)
    elif "diagonal" in dmp:
        kw["damping"] = np.diag(np.asarray(dmp["diagonal"], float))
    if "damping" in kw:
        _check_positive_definite(f"{path} [damping]", kw["damping"])
    if "quadratic" in dmp:
        kw["quadratic_damping"] = np.asarray(dmp["quadratic"], float)

    kw["nomoto"] = {k: float(v) for k, v in doc.get("nomoto", {}).items()}
    kw["rudder"] = {k: float(v) for k, v in doc.get("rudder", {}).items()}
    acts = []
    for a in doc.get("actuators", []):
        fs = float(a.get("full_scale", 1.0))
        trim, span = (0.0, 1.0) if a["source"] in NORMALISED_SOURCES else (1500.0, 400.0)
        acts.append(ActuatorMap(source=a["source"], channel=int(a["channel"]), target=a["target"],
                                pwm_trim=float(a.get("pwm_trim", trim)), pwm_span=float(a.get("pwm_span", span)),
                                full_scale=fs, reverse_scale=float(a.get("reverse_scale", fs)), name=a.get("name")))
    kw["actuators"] = tuple(acts)
    actuator_allocation(kw["actuators"], f"{path} [[actuators]]")  # one name, trim and span per actuator
    kw["sensor_noise"] = {k: float(v) for k, v in doc.get("sensor_noise", {}).items()}
    kw["extra"] = {k: doc[k] for k in ("thrusters", "topics", "sensors", "steady_state") if k in doc}
    return Vessel(**kw)


def load_vessel(path: str | Path) -> Vessel:
    """Read a vessel TOML file.

    Parameters
    ----------
    path : str or Path
        The TOML file.

    Raises
    ------
    ConfigError
        Missing file, invalid TOML, or invalid content.
    """
    p, doc = read_toml(path, "vessel config")
    return parse_vessel(doc, str(p))
