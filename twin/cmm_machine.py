"""The coordinate measuring machine of the twin (document 002): its setup and a program run at 1 ms.

The cell: the bridge CMM of ``models/cmm`` (three servo axes and an indexable head, 1 ms),
the scenario's touch probe on its head, the part at its true pose on the table. A program's
coordinates are the part's, as aligned at the scenario's nominal pose (the alignment a
measurement program starts from); the part lies at the true pose.

* :func:`cmm_setup`: the static things of a scenario: the part, its index, the styli as the
  planners see them (part frame), the swept clearance check, the machine's limits.
* :func:`execute`: a program run at 1 ms: every move a straight line of the head with a
  trapezoidal speed law (the transit speed and acceleration of ``[cmm]``), stylus changes as
  head indexing moves, probing moves at the probing speed until the probe triggers (the
  trigger model of :mod:`twin.sensors.touch_probe`, on the exact part) or the search distance
  is spent (a miss); the scales latched at the trigger give the hit. The probing move is
  :func:`twin.touch_probing.probing_move`, the axes its machine (:class:`_AxesProbingLine`). Then every 1 ms sample is
  checked for contact of the ball, stylus, body, head or ram with the exact part (python-fcl
  distances; samples skipped only where the probe cannot have reached the part since the last
  checked one); a ball contact inside a probing move is the measurement, anything else is a
  collision, counted and located.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np
import trimesh

from algorithms.arraytypes import FloatArray
from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.probing.cmm_planning import (
    Move,
    StylusReach,
    program_moves,
)
from algorithms.probing.program import MeasurePoint, Program, SelectStylus
from algorithms.probing.sweep import ProbeGeometry, ProbeSweep, frame_with_z
from twin.cell import add_workpiece
from twin.errors import TwinError
from twin.realize import load_workpiece_mesh
from twin.robot import GROUP_WORKPIECE, MODELS_DIR
from twin.scenario import Scenario
from twin.sensors.touch_probe import BALL_SITE, TouchProbe
from twin.touch_probing import probing_move

CMM_SCENE_XML = MODELS_DIR / "cmm" / "scene.xml"
AXES = ("axis_x", "axis_y", "axis_z")
HEAD_JOINTS = ("head_a", "head_b")
#: Contacts are checked on every sample where the probe may have come this close [m].
CONTACT_MARGIN_M = 0.0


@dataclass(frozen=True)
class MachineLimits:
    """What the CMM model says about itself (``models/cmm``)."""

    lo_m: np.ndarray
    hi_m: np.ndarray
    max_speed_m_s: float
    max_accel_m_s2: float
    head_radius_m: float
    ram_half_width_m: float


def _numeric(model: mujoco.MjModel, name: str) -> float:
    try:
        return float(model.numeric(name).data[0])
    except KeyError:
        raise TwinError(f"the CMM model lacks its numeric {name!r} (models/cmm/cmm.xml)") from None


def machine_limits(model: mujoco.MjModel) -> MachineLimits:
    rng = np.array([model.jnt_range[model.joint(a).id] for a in AXES])
    return MachineLimits(rng[:, 0].copy(), rng[:, 1].copy(), _numeric(model, "cmm_max_speed_m_s"),
                         _numeric(model, "cmm_max_accel_m_s2"), _numeric(model, "cmm_head_radius_m"),
                         _numeric(model, "cmm_ram_half_width_m"))


@dataclass
class CmmSetup:
    """A CMM scenario's static things (part frame = the nominal alignment)."""

    scenario: Scenario
    mesh: trimesh.Trimesh
    T_world_part_nominal: np.ndarray
    T_world_part_true: np.ndarray
    limits: MachineLimits
    styli: dict[str, StylusReach]
    probes: dict[str, ProbeGeometry]
    sweep: ProbeSweep
    index: MeshIndex

    def check(self, a: np.ndarray, b: np.ndarray, stylus: str):
        return self.sweep.check_move(a, b, self.probes[stylus])


def _cmm_spec(scenario: Scenario) -> mujoco.MjSpec:
    if not CMM_SCENE_XML.is_file():
        raise TwinError(f"the CMM model is missing: {CMM_SCENE_XML}")
    return mujoco.MjSpec.from_file(str(CMM_SCENE_XML))


def probe_geometry(scenario: Scenario, limits: MachineLimits, direction: np.ndarray, up: np.ndarray) -> ProbeGeometry:
    p = scenario.probe
    assert p is not None
    return ProbeGeometry(direction, p.ball_radius_m, p.stylus_radius_m, p.stylus_length_m, p.body_radius_m,
                         p.body_length_m, limits.head_radius_m, limits.ram_half_width_m, up)


def cmm_setup(scenario: Scenario, mesh: trimesh.Trimesh | None = None) -> CmmSetup:
    """The static things of a ``machine = "cmm"`` scenario."""
    if scenario.machine != "cmm" or scenario.cmm is None or scenario.probe is None:
        raise TwinError(f"scenario {scenario.name!r} is for machine = {scenario.machine!r}; twin cmm needs "
                        "machine = \"cmm\"")
    mesh = load_workpiece_mesh(scenario) if mesh is None else mesh
    model = _cmm_spec(scenario).compile()
    limits = machine_limits(model)
    if scenario.cmm.transit_speed_m_s > limits.max_speed_m_s or scenario.cmm.acceleration_m_s2 > limits.max_accel_m_s2:
        cmm = scenario.cmm
        raise TwinError(f"cmm.transit_speed_m_s = {cmm.transit_speed_m_s:g} and acceleration_m_s2 = "
                        f"{cmm.acceleration_m_s2:g} must be at most the machine's {limits.max_speed_m_s:g} m/s "
                        f"and {limits.max_accel_m_s2:g} m/s^2 (models/cmm)")
    wp = scenario.workpiece
    R_part_world = wp.T_world_workpiece_nominal[:3, :3].T
    up = R_part_world @ np.array([0.0, 0.0, 1.0])
    probes, styli = {}, {}
    for name in scenario.cmm.styli:
        d = R_part_world @ scenario.cmm.direction(name)
        probes[name] = probe_geometry(scenario, limits, d, up)
        styli[name] = StylusReach(d, probes[name].reach_m, scenario.probe.ball_radius_m)
    sweep = ProbeSweep(mesh.vertices, mesh.faces, scenario.cmm.clearance_m)
    return CmmSetup(scenario, mesh, wp.T_world_workpiece_nominal, wp.T_world_workpiece_true, limits, styli, probes,
                    sweep, sweep.index)



@dataclass(frozen=True)
class CmmHit:
    """One measured point of a program (part frame, metres).

    Attributes:
        label: the feature; point_m, normal: its nominal point and normal.
        measured_m: the measured surface point (ball centre from the latched scales, minus
            the ball radius along the nominal normal), or None for a miss.
        deviation_m: (measured - nominal) . normal, or None.
        trigger_t_s: time of the trigger [s], or None.
    """

    label: str
    point_m: np.ndarray
    normal: np.ndarray
    measured_m: np.ndarray | None
    deviation_m: float | None
    trigger_t_s: float | None


@dataclass(frozen=True)
class CmmContact:
    """An unintended contact of the probe with the part.

    Attributes:
        solid: "ball", "stylus", "body", "head" or "ram".
        statement: the program statement (0-based) whose move it happened in; kind: the move's kind.
        first_t_s, last_t_s: first and last sample in contact [s].
        ball_centre_m: (3,) the ball centre at the first contact (part frame) [m].
        part_point_m: (3,) the point of the part nearest the solid's centre there (part frame) [m].
    """

    solid: str
    statement: int
    kind: str
    first_t_s: float
    last_t_s: float
    ball_centre_m: np.ndarray
    part_point_m: np.ndarray


@dataclass
class CmmRun:
    """A program executed in the twin.

    Attributes:
        program: the program.
        t_s: (n,) sample times [s]; head_world_m: (n, 3) the head centre (true); head_angles_rad: (n, 2) A, B.
        ball_part_m: (n, 3) the true ball centre in the part's nominal frame [m].
        statement: (n,) the statement each sample belongs to; kind: (n,) index into MOVE_KINDS.
        hits: one per measured point; contacts: every unintended contact.
        path_length_m: the ball centre's travel; cycle_time_s: the program's duration.
    """

    program: Program
    t_s: np.ndarray
    head_world_m: np.ndarray
    head_angles_rad: np.ndarray
    ball_part_m: np.ndarray
    statement: np.ndarray
    kind: np.ndarray
    hits: list[CmmHit] = field(default_factory=list)
    contacts: list[CmmContact] = field(default_factory=list)
    path_length_m: float = 0.0
    cycle_time_s: float = 0.0

    @property
    def misses(self) -> int:
        return sum(h.measured_m is None for h in self.hits)


MOVE_KINDS = ("goto", "approach", "probe", "retract", "index", "brake")


def trapezoid(distance_m: float, v_max: float, a_max: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Arc length and speed at each step of a rest-to-rest move (the first sample after the start,
    the last at the end) with a trapezoidal (or triangular) speed law."""
    if distance_m <= 0:
        return np.zeros(1), np.zeros(1)
    t_acc = v_max / a_max
    if a_max * t_acc**2 >= distance_m:  # triangular
        t_acc = np.sqrt(distance_m / a_max)
        v_top, t_flat = a_max * t_acc, 0.0
    else:
        v_top, t_flat = v_max, (distance_m - a_max * t_acc**2) / v_max
    total = 2 * t_acc + t_flat
    n = max(1, int(np.ceil(total / dt)))
    t = np.arange(1, n + 1) * dt * (total / (n * dt))
    s = np.where(t < t_acc, 0.5 * a_max * t**2,
                 np.where(t < t_acc + t_flat, 0.5 * a_max * t_acc**2 + v_top * (t - t_acc),
                          distance_m - 0.5 * a_max * np.maximum(total - t, 0.0) ** 2))
    v = np.where(t < t_acc, a_max * t, np.where(t < t_acc + t_flat, v_top, a_max * np.maximum(total - t, 0.0)))
    s[-1], v[-1] = distance_m, 0.0
    return s, v


class _Machine:
    """The CMM cell stepping at 1 ms with servo references, recording every step."""

    def __init__(self, setup: CmmSetup):
        sc = setup.scenario
        spec = _cmm_spec(sc)
        self.probe = TouchProbe(sc.probe, sc.noise)  # type: ignore[arg-type]
        self.probe.attach(spec, spec.body("probe_mount"))
        T = setup.T_world_part_true
        m = setup.mesh
        add_workpiece(spec, m, T, GROUP_WORKPIECE, conaffinity=0)
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self.dt = float(self.model.opt.timestep)
        mdl = self.model
        self.qadr = np.array([mdl.jnt_qposadr[mdl.joint(j).id] for j in AXES + HEAD_JOINTS])
        self.vadr = np.array([mdl.jnt_dofadr[mdl.joint(j).id] for j in AXES + HEAD_JOINTS])
        self.act_pos = [mdl.actuator(f"{j}_pos").id for j in AXES + HEAD_JOINTS]
        self.act_vel = [mdl.actuator(f"{j}_vel").id for j in AXES + HEAD_JOINTS]
        self.ball_site = mdl.site(BALL_SITE).id
        self.t: list[float] = []
        self.q: list[np.ndarray] = []
        self.ball: list[np.ndarray] = []
        self.statement: list[int] = []
        self.kind: list[int] = []

    def reset(self, q0: np.ndarray) -> None:
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[self.qadr] = q0
        mujoco.mj_forward(self.model, self.data)

    def step(self, q_ref: np.ndarray, qd_ref: np.ndarray, statement: int, kind: str) -> np.ndarray:
        d = self.data
        for i, (ap, av) in enumerate(zip(self.act_pos, self.act_vel, strict=True)):
            d.ctrl[ap] = q_ref[i]
            d.ctrl[av] = qd_ref[i]
        mujoco.mj_step(self.model, d)
        ball = d.site_xpos[self.ball_site].copy()
        self.t.append(float(d.time))
        self.q.append(d.qpos[self.qadr].copy())
        self.ball.append(ball)
        self.statement.append(statement)
        self.kind.append(MOVE_KINDS.index(kind))
        return ball


def _angles(cmm_styli: dict, name: str) -> np.ndarray:
    a, b = cmm_styli[name]
    return np.radians([a, b])


def execute(program: Program, setup: CmmSetup, rng: np.random.Generator) -> CmmRun:
    """Run a program in the twin at 1 ms (see the module docstring).

    Raises:
        TwinError: a stylus the machine lacks, or a move that drives an axis past its range.
    """
    sc = setup.scenario
    cmm, probe = sc.cmm, sc.probe
    assert cmm is not None and probe is not None
    try:
        moves = program_moves(program, setup.styli)
    except AlgorithmError as exc:
        raise TwinError(f"program {program.name!r}: {exc}") from None
    if not moves:
        raise TwinError(f"program {program.name!r} makes no move")
    T_wp = setup.T_world_part_nominal
    reach = {k: (sc.cmm.direction(k), v.reach_m) for k, v in setup.styli.items()}  # type: ignore[union-attr]

    def head_of(ball_part: np.ndarray, stylus: str) -> np.ndarray:
        d, L = reach[stylus]
        return transform_points(T_wp, ball_part[None])[0] - L * d

    _check_ranges(program, moves, setup, head_of)
    machine = _Machine(setup)
    stylus0 = next(st.name for st in program.statements if isinstance(st, SelectStylus))
    q = np.concatenate([head_of(moves[0].start_m, stylus0), _angles(cmm.styli, stylus0)])
    machine.reset(q)
    hits: list[CmmHit] = []
    measures = {k: st for k, st in enumerate(program.statements) if isinstance(st, MeasurePoint)}
    i = 0
    while i < len(moves):
        mv = moves[i]
        if mv.kind == "index":
            q = _index(machine, q, _angles(cmm.styli, mv.stylus), cmm.index_time_s, mv.statement)
            i += 1
            continue
        if mv.kind == "probe":
            # the retract (the next move) starts where the machine stopped
            back = moves[i + 1]
            st = measures[mv.statement]
            hit, q = _probe(machine, q, mv, st, (head_of(back.end_m, back.stylus), back.statement),
                            (st.settings or program.settings).search_m, setup, rng)
            hits.append(hit)
            i += 2
            continue
        q = _line(machine, q, head_of(mv.end_m, mv.stylus), cmm.transit_speed_m_s, cmm.acceleration_m_s2,
                  mv.statement, mv.kind)
        i += 1
    t = np.array(machine.t)
    qs = np.array(machine.q)
    ball_world = np.array(machine.ball)
    ball_part = transform_points(inv_pose(T_wp), ball_world)
    run = CmmRun(program, t, qs[:, :3], qs[:, 3:], ball_part, np.array(machine.statement), np.array(machine.kind),
                 hits)
    run.path_length_m = float(np.linalg.norm(np.diff(ball_part, axis=0), axis=1).sum())
    run.cycle_time_s = float(t[-1]) if len(t) else 0.0
    run.contacts = find_contacts(run, setup)
    return run


def _check_ranges(program: Program, moves: list[Move], setup: CmmSetup, head_of) -> None:
    lim = setup.limits
    for mv in moves:
        for p in (mv.start_m, mv.end_m):
            h = head_of(p, mv.stylus)
            for k, ax in enumerate("XYZ"):
                if not lim.lo_m[k] - 1e-9 <= h[k] <= lim.hi_m[k] + 1e-9:
                    raise TwinError(
                        f"program {program.name!r}, statement {mv.statement + 1}: the {ax} axis would go to "
                        f"{1e3 * h[k]:.1f} mm, outside its range [{1e3 * lim.lo_m[k]:.0f}, {1e3 * lim.hi_m[k]:.0f}] mm")


def _line(machine: _Machine, q: np.ndarray, head_target: np.ndarray, v_max: float, a_max: float, statement: int,
          kind: str) -> np.ndarray:
    start = q[:3]
    delta = head_target - start
    dist = float(np.linalg.norm(delta))
    if dist < 1e-12:
        return q
    u = delta / dist
    s, v = trapezoid(dist, v_max, a_max, machine.dt)
    for sk, vk in zip(s, v, strict=True):
        machine.step(np.concatenate([start + sk * u, q[3:]]), np.concatenate([vk * u, [0.0, 0.0]]), statement, kind)
    return np.concatenate([head_target, q[3:]])


def _index(machine: _Machine, q: np.ndarray, angles: np.ndarray, time_s: float, statement: int) -> np.ndarray:
    n = max(1, int(round(time_s / machine.dt)))
    a0 = q[3:].copy()
    for k in range(1, n + 1):
        f = k / n
        smooth = f * f * (3 - 2 * f)
        rate = 6 * f * (1 - f) / time_s
        machine.step(np.concatenate([q[:3], a0 + smooth * (angles - a0)]),
                     np.concatenate([[0.0, 0.0, 0.0], rate * (angles - a0)]), statement, "index")
    return np.concatenate([q[:3], angles])


@dataclass(frozen=True)
class _ProbingLine:
    """A CMM probing move as the head's set-points (world frame, SI).

    Attributes:
        n_world: (3,) the point's outward normal; the head moves along ``-n_world``.
        speed_m_s: the probing speed (no ramp: the axes follow a constant-speed line).
        n_steps: 1 ms steps to the search end.
        statement: the program statement the move belongs to.
        R_world_probe: (3, 3) the probe frame (z along the stylus).
        retract_head_m: (3,) where the program's retract move takes the head.
        retract_statement: the retract move's statement.
    """

    n_world: np.ndarray
    speed_m_s: float
    n_steps: int
    statement: int
    R_world_probe: np.ndarray
    retract_head_m: np.ndarray
    retract_statement: int


class _AxesProbingLine:
    """The CMM as the probing engine's machine (:class:`twin.touch_probing.ProbingMachine`):
    set-points along a :class:`_ProbingLine`, one 1 ms step between two trigger checks, the
    head angles held; the scales latched at the trigger."""

    chunk_steps = 1

    def __init__(self, machine: _Machine, q: np.ndarray, line: _ProbingLine, scenario: Scenario,
                 rng: np.random.Generator):
        assert scenario.cmm is not None and scenario.probe is not None
        self.machine = machine
        self.line = line
        self.cmm = scenario.cmm
        self.deceleration_m_s2 = scenario.probe.stop_deceleration_m_s2
        self.rng = rng
        self.head_start_m = q[:3].copy()
        self.angles_rad = q[3:]
        self.t0 = len(machine.t)
        self.k = 0
        self.head_m = self._set_point(0)

    def _set_point(self, k: int) -> np.ndarray:
        """The head's set-point (3,) [m, world] after ``k`` steps of the probing move."""
        return self.head_start_m - k * self.line.speed_m_s * self.machine.dt * self.line.n_world

    @property
    def q(self) -> np.ndarray:
        """(5,) the machine's set-point now: head position [m] and head angles [rad]."""
        return np.concatenate([self.head_m, self.angles_rad])

    def lead_in(self) -> tuple[FloatArray, FloatArray]:
        """The sample recorded just before the move (its start), if any."""
        m = self.machine
        lo = max(self.t0 - 1, 0)
        return np.array(m.ball[lo:self.t0]).reshape(-1, 3), np.array(m.t[lo:self.t0])

    def advance(self, n_steps: int) -> tuple[FloatArray, FloatArray]:
        """Up to ``n_steps`` steps on along the line: true ball centres (world) and times."""
        m, ln = self.machine, self.line
        balls, times = [], []
        for k in range(self.k + 1, min(self.k + n_steps, ln.n_steps) + 1):
            balls.append(m.step(np.concatenate([self._set_point(k), self.angles_rad]),
                                np.concatenate([-ln.speed_m_s * ln.n_world, [0.0, 0.0]]), ln.statement, "probe"))
            times.append(m.t[-1])
            self.k = k
            self.head_m = self._set_point(k)
        return np.array(balls).reshape(-1, 3), np.array(times)

    def R_world_probe(self) -> FloatArray:
        return self.line.R_world_probe

    def latch(self, t_s: float) -> FloatArray:
        """The scales (3,) [m, head centre, world] latched at ``t_s``: interpolated between the
        two samples around it, plus the scales' noise."""
        ts = np.array(self.machine.t)
        qs = np.array(self.machine.q)
        j = int(np.searchsorted(ts, t_s))
        j = min(max(j, 1), len(ts) - 1)
        f = (t_s - ts[j - 1]) / (ts[j] - ts[j - 1])
        head = qs[j - 1, :3] + f * (qs[j, :3] - qs[j - 1, :3])
        return head + self.rng.normal(0.0, self.cmm.encoder_sigma_m, 3)

    def brake(self, trigger_t_s: float) -> FloatArray:
        """Brake to rest from the probing speed, from the set-point of the step that saw the
        trigger (the last one: the axes step one cycle between checks)."""
        m, ln = self.machine, self.line
        v, stop = ln.speed_m_s, self.deceleration_m_s2
        n_brake = int(np.ceil(v / stop / m.dt))
        pos = self.head_m.copy()
        for b in range(1, n_brake + 1):
            speed = max(v - stop * b * m.dt, 0.0)
            pos = pos - speed * m.dt * ln.n_world
            m.step(np.concatenate([pos, self.angles_rad]), np.concatenate([-speed * ln.n_world, [0.0, 0.0]]),
                   ln.statement, "brake")
        self.head_m = pos
        return m.ball[-1]

    def retract(self) -> None:
        """The program's retract move, from where the machine stopped."""
        ln = self.line
        self.head_m = _line(self.machine, self.q, ln.retract_head_m, self.cmm.transit_speed_m_s,
                            self.cmm.acceleration_m_s2, ln.retract_statement, "retract")[:3]


def _probe(machine: _Machine, q: np.ndarray, mv: Move, st: MeasurePoint, back: tuple[np.ndarray, int],
           search_m: float, setup: CmmSetup, rng: np.random.Generator) -> tuple[CmmHit, np.ndarray]:
    """The probing move ``mv`` along -normal at the probing speed until the trigger or the
    search end, then the program's retract move ``back`` (the head's target [m, world] and its
    statement), from where the machine stopped. Returns the hit and the machine's set-point
    (5,) after the retract."""
    sc = setup.scenario
    probe, cmm = sc.probe, sc.cmm
    assert probe is not None and cmm is not None
    r = probe.ball_radius_m
    n_part = np.asarray(st.normal)
    T_wp = setup.T_world_part_nominal
    total = float(np.linalg.norm(mv.end_m - mv.start_m)) + search_m
    v = probe.probing_speed_m_s
    d_world, L = cmm.direction(mv.stylus), setup.styli[mv.stylus].reach_m
    line = _ProbingLine(T_wp[:3, :3] @ n_part, v, int(np.ceil(total / v / machine.dt)), mv.statement,
                        frame_with_z(d_world), back[0], back[1])
    T_part_true_world = inv_pose(setup.T_world_part_true)

    def gap(c: np.ndarray) -> np.ndarray:
        # the exact part where it really lies: ball centres mapped into its true frame
        return setup.index.signed_distance(transform_points(T_part_true_world, c)) - r

    axes = _AxesProbingLine(machine, q, line, sc, rng)
    out = probing_move(axes, gap, machine.probe.pretravel, rng)
    if out.trigger is None or out.reading is None:
        return CmmHit(st.label, np.asarray(st.point_m), n_part, None, None, None), axes.q
    ball_world = out.reading + L * d_world
    ball_part = transform_points(inv_pose(T_wp), ball_world[None])[0]
    measured = ball_part - r * n_part
    dev = float((measured - np.asarray(st.point_m)) @ n_part)
    return CmmHit(st.label, np.asarray(st.point_m), n_part, measured, dev, out.trigger.trigger_t_s), axes.q


# ----------------------------------------------------------------------------- contacts
def find_contacts(run: CmmRun, setup: CmmSetup) -> list[CmmContact]:
    """Every unintended contact along the executed motion (see the module docstring)."""
    sc = setup.scenario
    T_wp = setup.T_world_part_nominal
    # Check in the part's TRUE frame: the probe's world pose mapped into the true part frame.
    T_true_inv = inv_pose(setup.T_world_part_true)
    R = T_true_inv[:3, :3]
    up = R @ np.array([0.0, 0.0, 1.0])
    ball_true = transform_points(T_true_inv, transform_points(T_wp, run.ball_part_m))
    sweep = setup.sweep  # its distances and inside test do not depend on its clearance
    probe_kind = MOVE_KINDS.index("probe")
    brake_kind = MOVE_KINDS.index("brake")
    lim = setup.limits
    out: list[CmmContact] = []
    n = len(run.t_s)
    open_: dict[str, int] = {}  # solid -> first sample of its contact in progress
    k = 0
    geom_cache: dict[tuple[float, float], ProbeGeometry] = {}
    while k < n:
        a, b = run.head_angles_rad[k]
        key = (round(float(a), 4), round(float(b), 4))
        if key not in geom_cache:
            d = np.array([np.sin(a) * np.cos(b), np.sin(a) * np.sin(b), -np.cos(a)])
            geom_cache[key] = probe_geometry(sc, lim, R @ d, up)
        g = geom_cache[key]
        measuring = run.kind[k] in (probe_kind, brake_kind)
        dists = sweep.solid_distances(ball_true[k], g)
        if measuring:
            dists["ball"] = np.inf
        touching = {s for s, dv in dists.items() if dv <= CONTACT_MARGIN_M}
        for s in list(open_):
            if s not in touching:
                out.append(_contact(s, open_.pop(s), k - 1, run, ball_true, setup, g))
        for s in touching:
            if s not in open_:
                open_[s] = k
        dmin = min(dists.values())
        if touching or not np.isfinite(dmin):
            k += 1
            continue
        # Skip the samples the probe cannot have reached the part in (translation only).
        k1 = k + 1
        travelled = 0.0
        while k1 < n and np.allclose(run.head_angles_rad[k1], run.head_angles_rad[k], atol=1e-9):
            travelled += float(np.linalg.norm(ball_true[k1] - ball_true[k1 - 1]))
            if travelled >= dmin or run.kind[k1] != run.kind[k]:
                break
            k1 += 1
        k = max(k1, k + 1)
    for s, k0 in open_.items():
        out.append(_contact(s, k0, n - 1, run, ball_true, setup, g))
    out.sort(key=lambda c: c.first_t_s)
    return out


def _contact(solid: str, k0: int, k_last: int, run: CmmRun, ball_true: np.ndarray, setup: CmmSetup,
             g: ProbeGeometry) -> CmmContact:
    """A contact event from sample ``k0`` to ``k_last``, located on the part (true frame: ``g``
    and ``ball_true`` are in it, and so is the part's own mesh)."""
    ball = run.ball_part_m[k0]
    offsets = {"ball": 0.0, "stylus": 0.5 * g.stylus_length_m, "body": g.stylus_length_m + 0.5 * g.body_length_m,
               "head": g.reach_m, "ram": g.reach_m}
    centre = ball_true[k0] - offsets[solid] * g.direction
    foot = setup.index.query(centre[None]).foot[0]
    return CmmContact(solid, int(run.statement[k0]), MOVE_KINDS[int(run.kind[k0])], float(run.t_s[k0]),
                      float(run.t_s[k_last]), ball.copy(), foot)


__all__ = ["CmmContact", "CmmHit", "CmmRun", "CmmSetup", "cmm_setup", "execute", "find_contacts", "trapezoid"]
