"""The recording of ``twin cmm``: the CMM cell with each program on its own entity, readable at a glance.

What the recording holds (world frame = the CMM's: granite top at z = 0, metres, ``sim_time`` [s];
every program starts at 0 s, so one time cursor compares them):

* ``world/part/mesh``: the part where it truly lies (translucent, so paths inside it show).
* ``world/machine/table``: the granite table (static). ``world/machine/<program>/bridge``,
  ``.../bridge/carriage``, ``.../carriage/ram``, ``.../ram/head``, ``.../head/probe_mount``: the
  moving bridge (Y), carriage (X), ram (Z), indexable head (A, B) and probe (body and stylus
  cylinders) of the ``models/cmm`` MuJoCo model, nested as the machine's kinematic chain and
  driven by that program's axis readings and head angles: each body's ``Transform3D`` in its
  parent's frame (a slide's translation, a head joint's rotation), sampled every
  :data:`SAMPLE_EVERY` 1 ms samples (20 ms), a row kept only where that body moved. Each program
  has its own machine, its head sphere in the program's colour; the shared view shows the
  machine of the program that collides (else the first; the others are there, switched off),
  and each program's tab shows its own. That is what a metrology engineer watches on the real
  machine: the ram and head coming down onto the part, and which solid meets it.
* ``world/cmm/<program>``: one toggle per program, in the program's colour:
  ``path`` the planned ball-centre path (thin static line, split at stylus changes; programs
  listed first are drawn thicker, so a program on the same path as another shows as a core
  inside its ring: Rerun has no draw order for 3D primitives, so colour and radius tell them
  apart, never an offset of the geometry); ``ball`` and ``stylus`` where the probe is at the
  time cursor (latest value only: no view accumulates them; the ball turns red while the probe
  is in an unintended contact); ``hits`` the measured points (labels on hover); ``misses``
  the nominal points of touches that missed (magenta, labelled); ``contacts`` the unintended
  contacts, grouped by statement and move, as large red labelled markers (solids, statement,
  move kind, time), and ``contacts/each`` every contact event.
* ``report``: a Markdown panel with the comparison table (the one ``twin cmm compare``
  writes, when given) and the legend: which colour is which program, what each marker means.

The layout: tabs of 3D views (all programs framed on the part; one per program; the whole
machine), next to the report. The stream carries no ``log_time``/``log_tick`` timelines and no
per-sample ``rr.log`` calls: the motion goes in with ``rr.send_columns``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from scipy.spatial.transform import Rotation

from algorithms.errors import AlgorithmError
from algorithms.geometry.se3 import transform_points
from algorithms.probing.cmm_planning import program_moves
from twin import evaluate
from twin.cmm_machine import CMM_SCENE_XML, CmmContact, CmmRun, CmmSetup
from twin.sensors.touch_probe import TouchProbe
from twin.viz.blueprint import REPORT_ENTITY, TIMELINE, eye_on
from twin.viz.cell import geom_mesh
from twin.viz.columns import quiet_timelines

#: (colour, its name in the legend) of the three planners' programs.
PROGRAM_COLOURS: dict[str, tuple[list[int], str]] = {
    "baseline": ([255, 150, 30], "orange"), "document": ([40, 120, 255], "blue"),
    "full_check": ([40, 200, 90], "green")}
#: Colours of other programs (``twin cmm run``/``check``: "program"), in turn.
PALETTE: list[tuple[list[int], str]] = [([40, 120, 255], "blue"), ([255, 150, 30], "orange"),
                                        ([40, 200, 90], "green"), ([170, 60, 220], "purple"),
                                        ([0, 170, 170], "teal")]
CONTACT_COLOUR = [230, 0, 0]
MISS_COLOUR = [255, 0, 255]
#: The motion (probe, machine) is sampled every this many 1 ms samples (20 ms), and at the last.
SAMPLE_EVERY = 20
#: A machine body's sample is kept where it moved this far [m] or turned this much [rad] since the last kept one.
MOVED_M = 1e-4
TURNED_RAD = 1e-4
#: Path line radius of the first program, as a fraction of the part's size, and of each next one.
PATH_RADIUS_FRACTION = 0.004
PATH_RADIUS_STEP = 0.0012
#: Contact markers: radius as a fraction of the part's size (at least twice the ball's radius).
CONTACT_RADIUS_FRACTION = 0.03
#: Geoms of the machine model not drawn: the floor (far below, 4 m wide) and the probe's ball
#: (each program's ``ball`` draws it, red while in contact).
SKIPPED_GEOMS = ("floor", "probe_ball")
#: The machine structure is drawn this opaque (0-255), so the probe shows through the ram.
MACHINE_ALPHA = 170


@dataclass(frozen=True)
class ProgramStyle:
    """How a program is drawn: its colour (RGB 0-255) and name, and its path's line radius [m]."""

    colour: list[int]
    colour_name: str
    path_radius_m: float


def program_styles(names: Sequence[str], part_size_m: float) -> dict[str, ProgramStyle]:
    """A distinct colour for each program, and path radii decreasing in the order given."""
    free = [c for c in PALETTE if c[0] not in [PROGRAM_COLOURS[n][0] for n in names if n in PROGRAM_COLOURS]]
    free = free or PALETTE
    out: dict[str, ProgramStyle] = {}
    others = 0
    for k, name in enumerate(names):
        if name in PROGRAM_COLOURS:
            colour, word = PROGRAM_COLOURS[name]
        else:
            colour, word = free[others % len(free)]
            others += 1
        fraction = max(PATH_RADIUS_FRACTION - k * PATH_RADIUS_STEP, 0.25 * PATH_RADIUS_STEP)
        out[name] = ProgramStyle(list(colour), word, fraction * part_size_m)
    return out


def followed_program(runs: dict[str, CmmRun]) -> str:
    """The program whose machine the shared view shows: the first with a contact, else the first."""
    return next((m for m, r in runs.items() if r.contacts), next(iter(runs)))


def save_cmm_recording(path: str | Path, setup: CmmSetup, runs: dict[str, CmmRun],
                       app_id: str = "scan_twin_cmm", *, table: str | None = None,
                       title: str | None = None) -> Path:
    """Write the ``.rrd`` of one or more program runs on one scenario (world frame).

    Args:
        table: the comparison table (Markdown) to head the report panel, e.g. the one of
            ``twin cmm compare``; title: the report's title (default: the scenario's name).
    """
    path = Path(path)
    if not runs:
        raise ValueError("save_cmm_recording needs at least one program run")
    rec = rr.RecordingStream(app_id)
    quiet_timelines(rec)
    T_true = evaluate.true_part_pose_world(setup)
    part_size_m = float(np.ptp(setup.mesh.vertices, axis=0).max())
    styles = program_styles(list(runs), part_size_m)
    machine = machine_model(setup)
    with rec:
        rec.save(str(path))
        focus_world = transform_points(T_true, setup.mesh.bounds.mean(axis=0)[None])[0]
        _send_blueprint(list(runs), followed_program(runs), focus_world, part_size_m, machine)
        rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        mesh = setup.mesh
        rr.log("world/part/mesh", rr.Mesh3D(vertex_positions=transform_points(T_true, mesh.vertices),
                                            triangle_indices=mesh.faces,
                                            vertex_normals=mesh.vertex_normals @ T_true[:3, :3].T,
                                            albedo_factor=[190, 160, 110, 120]), static=True)
        _log_machine_geoms("world/machine/table", machine, {0: ""}, None)
        for name, run in runs.items():
            idx = sample_indices(len(run.t_s), SAMPLE_EVERY)
            _log_machine_geoms(f"world/machine/{name}", machine, moving_bodies(machine), styles[name].colour)
            _log_machine_motion(f"world/machine/{name}", machine, run, idx)
            _log_program(f"world/cmm/{name}", run, setup, idx, styles[name], part_size_m)
        text = report_markdown(setup, runs, styles, table=table, title=title)
        rr.log(REPORT_ENTITY, rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)
        rec.flush()
    return path


# ----------------------------------------------------------------------------- the machine
def machine_model(setup: CmmSetup) -> mujoco.MjModel:
    """The CMM of ``models/cmm`` with the scenario's probe on its head (no part)."""
    sc = setup.scenario
    assert sc.probe is not None
    spec = mujoco.MjSpec.from_file(str(CMM_SCENE_XML))
    TouchProbe(sc.probe, sc.noise).attach(spec, spec.body("probe_mount"))
    return spec.compile()


def _drawn_geoms(model: mujoco.MjModel, body: int) -> list[int]:
    return [g for g in range(model.ngeom)
            if model.geom_bodyid[g] == body and model.geom(g).name not in SKIPPED_GEOMS]


def moving_bodies(model: mujoco.MjModel) -> dict[int, str]:
    """The bodies with geoms drawn (not the world), each with its entity path under a machine's
    root: the kinematic chain of drawn bodies, ``bridge/carriage/ram/head/probe_mount``."""
    drawn = [b for b in range(1, model.nbody) if _drawn_geoms(model, b)]
    out = {}
    for b in drawn:
        chain, a = [], b
        while a != 0:
            if a in drawn:
                chain.append(model.body(a).name)
            a = int(model.body_parentid[a])
        out[b] = "/".join(reversed(chain))
    return out


def _drawn_parent(model: mujoco.MjModel, body: int, drawn: dict[int, str]) -> int:
    a = int(model.body_parentid[body])
    while a != 0 and a not in drawn:
        a = int(model.body_parentid[a])
    return a


def _log_machine_geoms(root: str, model: mujoco.MjModel, bodies: dict[int, str],
                       head_colour: list[int] | None) -> None:
    """Static meshes of the bodies' geoms, each in its body's frame (``root/<body path>/<geom>``;
    the world body's (0) geoms directly under ``root``)."""
    for b, body_path in bodies.items():
        parent = root if b == 0 else f"{root}/{body_path}"
        children = {p.rsplit("/", 1)[-1] for p in bodies.values() if p.startswith(f"{body_path}/")}
        for g in _drawn_geoms(model, b):
            mesh = geom_mesh(model, g)
            if mesh is None:
                continue
            name = model.geom(g).name or f"geom{g}"
            rgba = (np.asarray(model.geom_rgba[g]) * 255).astype(np.uint8)
            if b != 0 and not name.startswith("probe"):
                rgba[3] = MACHINE_ALPHA
            if name == "head" and head_colour is not None:
                rgba[:3] = head_colour
            entity = f"{parent}/{name}" + ("_geom" if name in children else "")
            rr.log(entity, rr.Mesh3D(vertex_positions=mesh.vertices, triangle_indices=mesh.faces,
                                     vertex_normals=mesh.vertex_normals, albedo_factor=rgba), static=True)


def machine_body_poses(model: mujoco.MjModel, head_world_m: np.ndarray, head_angles_rad: np.ndarray,
                       bodies: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """World poses of ``bodies`` for the axis readings (k, 3) [m, head centre, world] and head
    angles (k, 2) [rad, A then B]: positions (k, nb, 3) [m] and rotations (k, nb, 3, 3)."""
    data = mujoco.MjData(model)
    adr = [model.jnt_qposadr[model.joint(j).id] for j in ("axis_x", "axis_y", "axis_z", "head_a", "head_b")]
    k = len(head_world_m)
    pos_world_m = np.empty((k, len(bodies), 3))
    R_world_body = np.empty((k, len(bodies), 3, 3))
    for i in range(k):
        data.qpos[adr] = np.concatenate([head_world_m[i], head_angles_rad[i]])
        mujoco.mj_kinematics(model, data)
        pos_world_m[i] = data.xpos[bodies]
        R_world_body[i] = data.xmat[bodies].reshape(-1, 3, 3)
    return pos_world_m, R_world_body


def _changed(pos_m: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Indices of the samples kept for one body: the first, and each one where it moved (or
    turned) past :data:`MOVED_M` / :data:`TURNED_RAD` since the last kept one."""
    keep = [0]
    for i in range(1, len(pos_m)):
        j = keep[-1]
        cos = np.clip((np.trace(R[j].T @ R[i]) - 1.0) / 2.0, -1.0, 1.0)
        if np.linalg.norm(pos_m[i] - pos_m[j]) > MOVED_M or np.arccos(cos) > TURNED_RAD:
            keep.append(i)
    return np.array(keep)


def _log_machine_motion(root: str, model: mujoco.MjModel, run: CmmRun, idx: np.ndarray) -> None:
    """Each moving body's pose in its parent's frame on ``sim_time`` (``root/<body path>``): one
    row where it moved, so an axis at rest, or the head between stylus changes, costs nothing."""
    if len(idx) == 0:
        return
    drawn = moving_bodies(model)
    bodies = list(drawn)
    pos_m, R = machine_body_poses(model, run.head_world_m[idx], run.head_angles_rad[idx], bodies)
    for j, b in enumerate(bodies):
        p = _drawn_parent(model, b, drawn)
        if p == 0:
            rel_m, R_rel = pos_m[:, j], R[:, j]
        else:
            jp = bodies.index(p)
            R_par_T = np.swapaxes(R[:, jp], 1, 2)
            rel_m = np.einsum("kij,kj->ki", R_par_T, pos_m[:, j] - pos_m[:, jp])
            R_rel = R_par_T @ R[:, j]
        keep = _changed(rel_m, R_rel)
        # a slide logs only its translation, a joint of the head only its rotation (identity elsewhere)
        moves = bool(np.abs(rel_m).max() > 1e-9)
        turns = bool(np.abs(R_rel - np.eye(3)).max() > 1e-9)
        if not (moves or turns):
            continue
        columns = rr.Transform3D.columns(translation=rel_m[keep] if moves else None,
                                         quaternion=Rotation.from_matrix(R_rel[keep]).as_quat() if turns else None)
        rr.send_columns(f"{root}/{drawn[b]}", indexes=[rr.TimeColumn(TIMELINE, duration=run.t_s[idx[keep]])],
                        columns=columns)


# ----------------------------------------------------------------------------- a program
def sample_indices(n: int, every: int) -> np.ndarray:
    """Every ``every``-th of ``n`` samples, and the last."""
    if n == 0:
        return np.zeros(0, dtype=int)
    return np.unique(np.r_[np.arange(0, n, every), n - 1])


def in_contact(t_s: np.ndarray, contacts: Sequence[CmmContact]) -> np.ndarray:
    """(k,) bool: whether a contact lies in each sample's interval (t[i-1], t[i]] (decimated
    samples: a contact shorter than the step still shows)."""
    t = np.asarray(t_s, dtype=np.float64)
    before = np.r_[-np.inf, t[:-1]]
    out = np.zeros(len(t), dtype=bool)
    for c in contacts:
        out |= (t >= c.first_t_s) & (before < c.last_t_s)
    return out


def planned_strips(run: CmmRun, setup: CmmSetup) -> list[np.ndarray]:
    """The program's planned ball-centre path (part frame, nominal alignment) [m]: one strip per
    stylus, broken at each stylus change (the ball does not travel the index's straight line)."""
    try:
        moves = program_moves(run.program, setup.styli)
    except AlgorithmError:
        return [run.ball_part_m[::SAMPLE_EVERY]]
    strips: list[list[np.ndarray]] = [[]]
    for mv in moves:
        if mv.kind == "index":
            strips.append([])
            continue
        if not strips[-1]:
            strips[-1].append(np.asarray(mv.start_m))
        strips[-1].append(np.asarray(mv.end_m))
    return [np.array(s) for s in strips if len(s) >= 2]


def _log_program(root: str, run: CmmRun, setup: CmmSetup, idx: np.ndarray, style: ProgramStyle,
                 part_size_m: float) -> None:
    T_nom = setup.T_world_part_nominal
    sc = setup.scenario
    assert sc.probe is not None
    ball_radius_m = sc.probe.ball_radius_m
    strips_world = [transform_points(T_nom, s) for s in planned_strips(run, setup)]
    if strips_world:
        rr.log(f"{root}/path", rr.LineStrips3D(strips_world, colors=[style.colour], radii=style.path_radius_m),
               static=True)
    if len(idx):
        _log_probe(root, run, T_nom, idx, style, ball_radius_m, max(sc.probe.stylus_radius_m, 0.3e-3))
    hits = [h for h in run.hits if h.measured_m is not None]
    if hits:
        rr.log(f"{root}/hits", rr.Points3D(transform_points(T_nom, np.array([h.measured_m for h in hits])),
                                           radii=0.6 * ball_radius_m, colors=[style.colour],
                                           labels=[h.label for h in hits], show_labels=False), static=True)
    misses = [h for h in run.hits if h.measured_m is None]
    if misses:
        rr.log(f"{root}/misses", rr.Points3D(transform_points(T_nom, np.array([h.point_m for h in misses])),
                                             radii=1.5 * ball_radius_m, colors=[MISS_COLOUR],
                                             labels=[f"MISS {h.label}" for h in misses], show_labels=True),
               static=True)
    if run.contacts:
        _log_contacts(f"{root}/contacts", run.contacts, evaluate.true_part_pose_world(setup),
                      max(CONTACT_RADIUS_FRACTION * part_size_m, 2 * ball_radius_m))


def _log_probe(root: str, run: CmmRun, T_nom: np.ndarray, idx: np.ndarray, style: ProgramStyle,
               ball_radius_m: float, stylus_radius_m: float) -> None:
    """The probe at each sample (latest value shown): ball (red while in contact) and stylus
    line from the ball centre to the head centre [m, world]."""
    ball_world_m = transform_points(T_nom, run.ball_part_m[idx])
    head_world_m = run.head_world_m[idx]
    times = [rr.TimeColumn(TIMELINE, duration=run.t_s[idx])]
    colours = np.tile(np.asarray(style.colour, dtype=np.uint8), (len(idx), 1))
    colours[in_contact(run.t_s[idx], run.contacts)] = CONTACT_COLOUR
    rr.send_columns(f"{root}/ball", indexes=times, columns=rr.Points3D.columns(positions=ball_world_m, colors=colours))
    rr.log(f"{root}/ball", rr.Points3D.from_fields(radii=ball_radius_m), static=True)
    strips = np.stack([ball_world_m, head_world_m], axis=1)
    rr.send_columns(f"{root}/stylus", indexes=times,
                    columns=rr.LineStrips3D.columns(strips=list(strips)).partition([1] * len(idx)))
    rr.log(f"{root}/stylus", rr.LineStrips3D.from_fields(radii=stylus_radius_m, colors=[style.colour]), static=True)


@dataclass(frozen=True)
class ContactGroup:
    """The contact events of one move of a statement: the solids (in order of their first
    contact, each with its count of events), the first and last times [s], the first event."""

    statement: int
    kind: str
    solids: tuple[tuple[str, int], ...]
    first_t_s: float
    last_t_s: float
    first: CmmContact

    @property
    def label(self) -> str:
        """e.g. "ram, head x46, body: statement 9 (approach), t 4.74-5.88 s" (statements 1-based)."""
        solids = ", ".join(f"{s} x{n}" if n > 1 else s for s, n in self.solids)
        times = (f"t {self.first_t_s:.2f} s" if self.last_t_s - self.first_t_s < 5e-3
                 else f"t {self.first_t_s:.2f}-{self.last_t_s:.2f} s")
        return f"{solids}: statement {self.statement + 1} ({self.kind}), {times}"


def group_contacts(contacts: Sequence[CmmContact]) -> list[ContactGroup]:
    """Contacts grouped by statement and move kind, in order of their first time."""
    groups: dict[tuple[int, str], list[CmmContact]] = {}
    for c in sorted(contacts, key=lambda c: c.first_t_s):
        groups.setdefault((c.statement, c.kind), []).append(c)
    out = []
    for (statement, kind), cs in groups.items():
        counts: dict[str, int] = {}
        for c in cs:
            counts[c.solid] = counts.get(c.solid, 0) + 1
        out.append(ContactGroup(statement, kind, tuple(counts.items()), cs[0].first_t_s,
                                max(c.last_t_s for c in cs), cs[0]))
    return out


def _log_contacts(entity: str, contacts: Sequence[CmmContact], T_world_part_true: np.ndarray,
                  radius_m: float) -> None:
    """Large red labelled markers (one per statement's move, at its first contact's point of the
    part) and every contact event under ``entity/each`` (labels on hover); part points located
    in the true part frame."""
    groups = group_contacts(contacts)
    where_world_m = transform_points(T_world_part_true, np.array([g.first.part_point_m for g in groups]))
    rr.log(entity, rr.Points3D(where_world_m, radii=radius_m, colors=[CONTACT_COLOUR],
                               labels=[g.label for g in groups], show_labels=True), static=True)
    each_world_m = transform_points(T_world_part_true, np.array([c.part_point_m for c in contacts]))
    each = [ContactGroup(c.statement, c.kind, ((c.solid, 1),), c.first_t_s, c.last_t_s, c).label for c in contacts]
    rr.log(f"{entity}/each", rr.Points3D(each_world_m, radii=0.35 * radius_m, colors=[CONTACT_COLOUR],
                                         labels=each, show_labels=False), static=True)


# ----------------------------------------------------------------------------- report and layout
def summary_rows(runs: dict[str, CmmRun], styles: dict[str, ProgramStyle]) -> str:
    """The per-program legend table (Markdown): colour, points, misses, contacts, path, time."""
    head = ("| program | colour | path line [mm] | points measured | misses | contact events | path [mm] | "
            "cycle [s] |\n|---|---|---|---|---|---|---|---|\n")
    lines = []
    for m, r in runs.items():
        s = styles[m]
        measured = sum(h.measured_m is not None for h in r.hits)
        lines.append(f"| {m} | {s.colour_name} (#{''.join(f'{c:02x}' for c in s.colour)}) | "
                     f"{2e3 * s.path_radius_m:.2f} wide | {measured} of {len(r.hits)} | {r.misses} | "
                     f"{len(r.contacts)} | {1e3 * r.path_length_m:.0f} | {r.cycle_time_s:.1f} |")
    return head + "\n".join(lines) + "\n"


def report_markdown(setup: CmmSetup, runs: dict[str, CmmRun], styles: dict[str, ProgramStyle], *,
                    table: str | None = None, title: str | None = None) -> str:
    """The report panel: the comparison table (if given), the legend, the contacts of each program."""
    followed = followed_program(runs)
    parts = [f"# {title or setup.scenario.name}\n"]
    if table:
        parts.append(f"## Comparison\n\n{table.strip()}\n")
    parts.append(f"## Programs and colours\n\n{summary_rows(runs, styles)}")
    parts.append(
        "## Legend\n\n"
        "- **Path** (thin line, program's colour): the planned ball-centre path. Programs listed first are "
        "drawn wider, so a program that shares another's path shows as a core inside its ring.\n"
        "- **Ball and stylus** (program's colour): where the probe is at the time cursor; the ball turns "
        "**red** while the probe touches the part where it should not.\n"
        "- **Touch points**: small spheres in the program's colour at the measured points (hover for the "
        "feature).\n"
        "- **Contacts**: large **red** spheres, labelled solids, statement, move and time (one per move of a "
        "statement, where its first contact is; the small red dots are every contact event, hover for each).\n"
        "- **Misses**: **magenta** spheres at the nominal point of a touch that found no surface.\n"
        f"- **Machine**: bridge, carriage, ram, head (program's colour) and probe of the program run; the "
        f"view *all programs* shows {followed}'s machine, each program's tab its own. Part: translucent, "
        "at its true pose.\n")
    for m, r in runs.items():
        if r.contacts:
            groups = group_contacts(r.contacts)
            parts.append(f"## {m}: {len(r.contacts)} contact events\n\n"
                         + "\n".join(f"- {g.label}" for g in groups) + "\n")
    return "\n".join(parts)


def _send_blueprint(names: list[str], followed: str, focus_world: np.ndarray, part_size_m: float,
                    machine: mujoco.MjModel) -> None:
    """Tabs of 3D views (all programs; one per program, where there are several; the whole
    machine) beside the report.
    No view accumulates over time: the probe and the machine show their latest pose."""
    eye = eye_on(focus_world, 2.5 * part_size_m)

    def others_hidden(shown: str) -> dict:
        return {f"world/machine/{m}": rrb.EntityBehavior(visible=False) for m in names if m != shown}

    shared = rrb.Spatial3DView(origin="world", name="all programs", eye_controls=eye,
                               overrides=others_hidden(followed))
    own = [rrb.Spatial3DView(origin="world", name=m, eye_controls=eye,
                             contents=["world/part/**", "world/machine/table/**", f"world/machine/{m}/**",
                                       f"world/cmm/{m}/**"]) for m in names] if len(names) > 1 else []
    whole = rrb.Spatial3DView(origin="world", name="machine", overrides=others_hidden(followed),
                              eye_controls=eye_on(np.asarray(machine.stat.center), 0.8 * float(machine.stat.extent)))
    layout = rrb.Horizontal(rrb.Tabs(shared, *own, whole, active_tab=0),
                            rrb.TextDocumentView(origin=REPORT_ENTITY, name="report"), column_shares=[3, 2])
    rr.send_blueprint(rrb.Blueprint(layout, rrb.TimePanel(timeline=TIMELINE, play_state="paused"),
                                    rrb.SelectionPanel(state="collapsed"), collapse_panels=False))
