"""``twin/ActiveProbe-v0``: choose the next touch-probe point to pin the part down fastest.

The touch-probe sibling of ``twin/ActiveScan-v0`` (:mod:`twin.env.active_scan`; the episodes,
the estimate and the stopping rule are :mod:`twin.env.base`'s). Each step the agent names a
line of sight onto the part; where it first meets the CAD model at the current estimate is the
target ``p``, with the model's smooth outward normal ``n`` there. The probe, its stylus straight
down, makes ONE probing move in the true cell at 1 ms (:class:`twin.probing.ProbingProgram`):
up to the safe height, across, down to ``approach_m`` off ``p`` along ``n``, then along ``-n``
until it triggers or has searched ``search_m`` past the expected surface (a miss: reported,
never a point), and back to the approach point. The recorded ball centre (joint encoders
latched at the trigger, nominal kinematics), corrected by the qualification's ball-centre
offset, is the new point; the part is re-localized on every ball centre so far
(:func:`algorithms.registration.bayes.localize_map` with ``offset_m`` the qualified effective
ball radius: the centres lie that far outside the surface; no beams, no per-reading biases;
the point noise is :func:`twin.qualification.probe_sigma_m`).

The action is four numbers in [-1, 1], mapped linearly as :mod:`twin.env.views` maps a laser
view (the stand-off and line direction mean nothing to a probe):

====  ================  =================================================
 0    azimuth           [-180, 180] deg about world z
 1    elevation         [``ELEVATION_MIN_DEG``, 90] deg above the table
 2    aim offset e1     [-R, R], R the radius of the part's bounding sphere
 3    aim offset e2     [-R, R]
====  ================  =================================================

The line of sight runs along ``-u`` (``u`` from the part towards the viewer, at that azimuth
and elevation) through the aim point, the part's centre moved by the offsets in the plane
normal to ``u``. A target is refused, before anything moves, when the line misses the part,
when a straight-down stylus cannot touch ``p`` along its normal
(:func:`algorithms.probing.point_planning.feasible_candidates`: the normal faces down, ``p``
lies near an edge, the ball or the stylus would meet the part first), when the ball's path
comes within ``clearance_m`` of the table, or when the arm cannot reach the approach and
search ends at any spin of the probe about its stylus with its links off the table and the
laser's housing clear of the part (:class:`twin.probing.ReachCheck`, which also picks the spin).

Qualification: the probe's effective ball radius (which absorbs the mean sideways
pre-travel) and ball-centre offset come from probing the cell's reference sphere
(:func:`twin.qualification.qualification_targets`, :func:`twin.qualification.qualify`). They belong to the
probe, not to the episode: each scenario is qualified ONCE, at construction, in its own true
cell with the scenario's own seed, and the result is kept for every episode (construction
takes a few seconds per scenario). With robot-side errors switched on in a scenario (kinematic
or hand-eye errors, drawn per episode), an episode's true arm differs from the qualified one.

A ball that touches a tessellated curved surface on an edge or a vertex of its facets (about
2 % of ball centres 1 mm off random points of the hemisphere and bottle punches) is fitted by
its distance to that edge or vertex (``localize_map`` with ``offset_m``), as the ball touches it.

The spaces, rewards and episode rules are in :class:`ActiveProbeEnv`'s docstring.

Actions outside [-1, 1] are clipped (``info["clipped"]``); an action of the wrong shape or with a
non-finite value is refused with ``ValueError``; so is, at construction, a scenario without a
``[probe]`` table, one whose part the probe cannot reach, or one whose reference sphere the
qualification misses.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.probing.point_planning import REASONS, feasible_candidates
from algorithms.registration.bayes import MapResult, localize_map, normalized_innovations
from twin.cell import Cell
from twin.env.base import (
    DEFAULT_MAX_STEPS,
    ActiveLocalizationEnv,
    EnvScenario,
    ScenarioChoice,
    prepare,
    seed_realized,
)
from twin.env.views import ELEVATION_MIN_DEG, VIEW_AIM_OFFSETS, decode_action, segment_centre, view_directions
from twin.errors import TwinError
from twin.probing import (
    STYLUS_AXIS_WORLD,
    ProbeHit,
    ProbeTarget,
    ProbingProgram,
    ReachCheck,
    build_probe_cell,
    joint_state_of,
    safe_height_world,
)
from twin.qualification import Qualification, probe_sigma_m, qualification_targets, qualify
from twin.realize import Realized
from twin.replay import contact_records
from twin.scenario import Scenario
from twin.sensors.touch_probe import probe_spec

__all__ = ["ACTION_SIZE", "DEFAULT_SCENARIOS", "ActiveProbeEnv",
           "ProbeResult", "ProbeScenario", "probe_target", "view_action"]

DEFAULT_SCENARIOS = ("locate_hemisphere_punch.toml",)
ACTION_SIZE = 4
#: Lines of sight tried at construction, aimed at the part's centre, to check that the probe
#: reaches the part at all: (azimuth, elevation) [deg].
CHECK_VIEWS_DEG = [(az, el) for el in (90.0, 60.0, 35.0) for az in range(-180, 180, 30)]


@dataclass(frozen=True)
class ProbeScenario(EnvScenario):
    """A scenario prepared for probing: :class:`twin.env.base.EnvScenario`, the probe's
    qualification on the reference sphere (once per scenario) and the reach check."""

    qualification: Qualification
    reach: ReachCheck


@dataclass(frozen=True)
class ProbeResult:
    """One probing move as the environment saw it (robot base frame, SI units).

    Attributes:
        points_base: (M, 3) the recorded ball centre corrected by the qualification's offset
            (M = 1 on a hit, 0 otherwise) [m].
        approach_base: (M, 3) the direction the ball moved along to it (the target's ``-n``).
        duration_s: the motion's duration [s].
        contacts: the collisions found over the motion (ContactRecord).
        hit: the probing move's outcome (None when the move stopped short of it).
    """

    points_base: np.ndarray
    approach_base: np.ndarray
    duration_s: float
    contacts: list
    hit: ProbeHit | None


def view_action(action: np.ndarray) -> np.ndarray:
    """The laser view action (:func:`twin.env.views.decode_action`) of a probe action: the
    same azimuth, elevation and aim offsets; stand-off and line direction at mid-range."""
    return np.array([action[0], action[1], 0.0, 0.0, action[2], action[3]])


def probe_target(action: np.ndarray, es: EnvScenario, reach: ReachCheck,
                 T_base_workpiece: np.ndarray) -> ProbeTarget | str:
    """The probe target an action names on the CAD model at ``T_base_workpiece`` (module
    docstring), or why it cannot be probed.

    Args:
        action: (4,) in [-1, 1].
        es: the prepared scenario; reach: the arm's reach check for its probe.
        T_base_workpiece: (4, 4) the pose the target is planned at (the current estimate).

    Returns:
        The target (point and outward normal in the robot base frame, the spin that reaches
        it), or a sentence saying why not.
    """
    sc = es.scenario
    p = probe_spec(sc)
    index = es.workpiece.index
    T_world_wp = sc.T_world_base @ T_base_workpiece
    view = decode_action(view_action(action), es.geometry)
    hit_world = segment_centre(view, T_world_wp, es.workpiece, es.geometry)
    if hit_world is None:
        return "the line of sight misses the part"
    cp = index.query(transform_points(inv_pose(T_world_wp), hit_world[None]))
    point_wp = cp.foot[0]
    normal_wp = index.smooth_normals(cp.face, cp.foot)[0]
    axis_wp = T_world_wp[:3, :3].T @ STYLUS_AXIS_WORLD
    feas = feasible_candidates(index, point_wp[None], normal_wp[None], stylus_axis=axis_wp,
                               ball_radius_m=p.ball_radius_m, stylus_radius_m=p.stylus_radius_m,
                               stylus_length_m=p.stylus_length_m, body_radius_m=p.body_radius_m,
                               body_length_m=p.body_length_m, approach_m=p.approach_m, search_m=p.search_m,
                               edge_margin_m=p.edge_margin_m, clearance_m=p.clearance_m)
    if not feas.mask[0]:
        why = REASONS[int(feas.reason[0])].replace("_", " ")
        return f"a straight-down stylus cannot probe the point along its normal ({why})"
    # the ball's path from the approach point to the search end, lowest end first: the table
    # is no part of the CAD model, and a ball that met it would trigger on it
    ends_wp = point_wp + np.outer([p.ball_radius_m + p.approach_m, p.ball_radius_m - p.search_m], normal_wp)
    lowest_m = float(transform_points(T_world_wp, ends_wp)[:, 2].min())
    if lowest_m - p.ball_radius_m < p.clearance_m:
        return f"the ball would pass {max(lowest_m - p.ball_radius_m, 0.0) * 1e3:.2f} mm above the table"
    spin = reach.spin(T_base_workpiece, point_wp, normal_wp)
    if spin is None:
        return ("the arm cannot reach the point with the stylus straight down at any spin (or the laser's "
                "housing would come near the part)")
    return ProbeTarget(transform_points(T_base_workpiece, point_wp[None])[0], T_base_workpiece[:3, :3] @ normal_wp,
                       "target", spin)


def _check_action(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """The action looking from that azimuth and elevation at the part's centre."""
    return np.array([azimuth_deg / 180.0, 2 * (elevation_deg - ELEVATION_MIN_DEG) / (90.0 - ELEVATION_MIN_DEG) - 1,
                     0.0, 0.0])


class ActiveProbeEnv(ActiveLocalizationEnv):
    """Choose the next touch-probe point to pin a clamped part down fastest.

    ## Description

    A UR5e with a touch-trigger probe (stylus straight down) stands before a part clamped near
    its nominal pose; where exactly, only the simulator knows. Each step the agent names a line
    of sight onto the part; the probe makes one probing move to where it meets the CAD model at
    the current estimate, along the surface normal, in the true cell at 1 ms (module
    docstring); the recorded ball centre is added and the part re-localized on every point so
    far, starting from the fixture's placement prior. The probe is qualified on the reference
    sphere once per scenario, at construction (a few seconds each).

    ## Action Space

    ``actions="box"`` (default): ``Box(-1, 1, (4,), float32)``, mapped linearly (values outside
    are clipped, ``info["clipped"]``):

    | index | component | range |
    |---|---|---|
    | 0 | azimuth of the line of sight (from the part towards the viewer) | [-180, 180] deg about world z |
    | 1 | elevation | [20, 90] deg above the table |
    | 2, 3 | aim offsets in the plane normal to the line | [-R, R], R the part's bounding radius |

    ``actions="views"``: ``Discrete(100)``, an index into ``view_table`` (the 20 view
    directions of :func:`twin.env.views.view_directions` times 5 aim offsets);
    ``info["action_mask"]`` and ``action_masks()`` say which targets can be probed at the
    part's nominal pose (:func:`probe_target`).

    ## Observation Space

    ``Dict`` of float32 boxes, as ``ActiveScan-v0``'s (:mod:`twin.env.observation`;
    ``gymnasium.wrappers.FlattenObservation`` makes it one vector of 66):

    | key | size | bounds | meaning |
    |---|---|---|---|
    | pose | 6 | [-1, 1] | estimate relative to the nominal pose, in prior sigmas (tanh) |
    | std | 6 | [-1, 1] | posterior standard deviation of each pose component: 1 prior, 0 tolerance (log scale) |
    | correlation | 15 | [-1, 1] | posterior correlations (upper triangle), workpiece frame |
    | worst_std | 2 | [-1, 1] | the stopping rule's worst rotation and translation deviation, scaled as std |
    | coverage | 14 | [0, 1] | ball centres per surface-normal direction (workpiece frame) |
    | surface | 14 | [0, 1] | the part's area per surface-normal direction |
    | joints | 6 | [-1, 1] | the arm's joints over their ranges |
    | progress | 3 | [0, 1] | steps left, last information gain, points so far |

    ## Rewards

    | term | value |
    |---|---|
    | information gain | the increase of ``log det`` of the posterior pose information [nats] |
    | motion | ``-time_cost_per_s`` per second of motion |
    | a target refused before moving, or a move that found no surface | ``-unreachable_penalty`` |
    | a collision (arm, housing, probe, or the ball outside a probing move) | ``-collision_penalty``, the end |

    ## Starting State

    ``reset(seed=...)`` draws, from that seed alone, the scenario, the part's true pose (the
    nominal pose moved by a Gaussian twist of ``placement_sigma_m`` and ``placement_sigma_deg``
    per axis) and the seeds of the cell's random streams; the probe starts at its safe
    position, nothing measured, the estimate at the nominal pose. The same seed and actions
    give the same episode.

    ## Episode End

    Terminated when the worst rotation and translation standard deviations (directions the
    part's shape cannot fix excepted) are within the tolerances, for a trusted fit that the
    next point confirms (``info["is_success"]``), or on a collision. Truncated after
    ``max_steps`` steps (30, as the registration's ``max_episode_steps``).

    ## Arguments

    Args:
        scenarios: a scenario file with a ``[probe]`` table, a :class:`Scenario`, or a list of
            them (names resolve in the project's ``scenarios/`` folder); each episode draws one.
        tolerance_m: the translation standard deviation that ends an episode [m].
        tolerance_deg: the rotation standard deviation that ends an episode [deg].
        max_steps: the step budget (truncation; ``gymnasium.make`` also wraps the environment
            in ``TimeLimit`` at the registration's 30: pass ``max_episode_steps`` with another).
        time_cost_per_s: reward lost per second of motion.
        unreachable_penalty: reward lost by a target that is refused or missed.
        collision_penalty: reward lost by a collision (the episode ends).
        placement_sigma_m: the fixture's placement scatter per axis [m] (the prior's standard
            deviation), or a (low, high) range each episode draws its scatter from,
            log-uniformly (a variety of clamps for training).
        placement_sigma_deg: the same for the rotations [deg].
        actions: ``"box"`` or ``"views"`` (Action Space).
        render_mode: None or ``"rgb_array"`` (EGL, else OSMesa, without a display); width,
            height: the rendered image [pixels].
    """

    action_size = ACTION_SIZE

    def __init__(self, scenarios: ScenarioChoice = DEFAULT_SCENARIOS, tolerance_m: float = 10e-6,
                 tolerance_deg: float = 0.01,
                 max_steps: int = DEFAULT_MAX_STEPS, time_cost_per_s: float = 0.5, unreachable_penalty: float = 1.0,
                 collision_penalty: float = 10.0, placement_sigma_m: float | tuple[float, float] = 1e-3,
                 placement_sigma_deg: float | tuple[float, float] = 0.5,
                 actions: str = "box", render_mode: str | None = None, width: int = 640, height: int = 480):
        super().__init__(scenarios, tolerance_m=tolerance_m, tolerance_deg=tolerance_deg, max_steps=max_steps,
                         time_cost_per_s=time_cost_per_s, unreachable_penalty=unreachable_penalty,
                         collision_penalty=collision_penalty, placement_sigma_m=placement_sigma_m,
                         placement_sigma_deg=placement_sigma_deg, render_mode=render_mode, width=width,
                         height=height, actions=actions)

    def _view_table(self) -> np.ndarray:
        return np.array([[az, el, o1, o2] for az, el in view_directions() for o1, o2 in VIEW_AIM_OFFSETS])

    def _view_mask(self, es: EnvScenario, table: np.ndarray) -> np.ndarray:
        if not isinstance(es, ProbeScenario):
            raise TypeError(f"ActiveProbe-v0 runs on a ProbeScenario, got {type(es).__name__}")
        T_base_nominal = inv_pose(es.scenario.T_world_base) @ es.scenario.workpiece.T_world_workpiece_nominal
        return np.array([not isinstance(probe_target(a, es, es.reach, T_base_nominal), str) for a in table])

    # ------------------------------------------------------------------ scenarios
    def _prepare(self, scenario: Scenario) -> ProbeScenario:
        """The scenario's mesh, cells and views, checked to be reachable, and the probe
        qualified on the reference sphere (once: module docstring)."""
        if scenario.probe is None:
            raise ValueError(f"scenario {scenario.name!r} has no [probe] table: ActiveProbe-v0 needs the touch "
                             "probe on the flange")
        es = prepare(scenario)
        realized = seed_realized(scenario, es.workpiece)   # the qualification's cell and streams
        reach = ReachCheck(es.nominal, realized)
        reasons: dict[str, int] = {}
        for az, el in CHECK_VIEWS_DEG:
            target = probe_target(_check_action(az, el), es, reach, realized.T_base_workpiece_nominal)
            if isinstance(target, ProbeTarget):
                break
            reasons[target] = reasons.get(target, 0) + 1
        else:
            why = "; ".join(f"{n} x {r}" for r, n in sorted(reasons.items(), key=lambda kv: -kv[1]))
            raise ValueError(f"scenario {scenario.name!r}: the probe reaches none of {len(CHECK_VIEWS_DEG)} points "
                             f"aimed at the part's centre (elevations 90, 60 and 35 deg, every 30 deg of azimuth): "
                             f"{why}; move the part or the robot base")
        return ProbeScenario(**{f.name: getattr(es, f.name) for f in fields(es)},
                             qualification=_qualify(realized, es.nominal), reach=reach)

    # ------------------------------------------------------------------ episodes
    def _start_episode(self, es: EnvScenario, realized: Realized) -> dict:
        if not isinstance(es, ProbeScenario):
            raise TypeError(f"ActiveProbe-v0 runs on a ProbeScenario, got {type(es).__name__}")
        cell = build_probe_cell(realized)
        program = ProbingProgram(realized, es.nominal, cell, realized.streams.generator("probe"))
        program.start()
        return {"program": program, "approach": np.zeros((0, 3)), "hits": 0, "misses": 0}

    # ------------------------------------------------------------------ steps
    def _measure(self, action: np.ndarray, events: dict) -> ProbeResult | None:
        """The target the action names, probed (None: refused before anything moved)."""
        ep = self.episode
        es, realized, program = ep["es"], ep["realized"], ep["program"]
        target = probe_target(action, es, es.reach, ep["T_base_est"])
        if isinstance(target, str):
            events["unreachable"] = target
            return None
        events["target_base"] = target.point.copy()
        T_world_est = realized.scenario.T_world_base @ ep["T_base_est"]
        first = len(program.logs["t"])
        try:
            hit = program.probe(target, safe_height_world(realized, T_world_est))
        except TwinError as exc:
            # a leg the IK could not follow: the arm stopped at rest where the last leg ended,
            # which is where the controller must plan the next move from
            hit = None
            events["unreachable"] = str(exc)
            program.solver.set_q(program.logs["q_ref"][-1][-1])
        duration_s, contacts = _motion_since(program, first)
        events["duration_s"] = duration_s
        events["hit"] = bool(hit is not None and hit.hit)
        if hit is not None and not hit.hit:
            ep["misses"] += 1
            events["unreachable"] = hit.miss
        if not events["hit"]:
            return ProbeResult(np.zeros((0, 3)), np.zeros((0, 3)), duration_s, contacts, hit)
        ep["hits"] += 1
        centre = hit.centre + hit.R_base_probe @ es.qualification.offset_probe_m
        return ProbeResult(centre[None], -target.normal[None], duration_s, contacts, hit)

    def _append(self, result: ProbeResult) -> None:
        ep = self.episode
        ep["approach"] = np.vstack([ep["approach"], result.approach_base])

    def _innovations(self, result: ProbeResult) -> np.ndarray:
        ep = self.episode
        return normalized_innovations(result.points_base, result.approach_base, ep["es"].workpiece.index,
                                      ep["T_base_est"], ep["fit"].covariance, self._point_sigma_m(),
                                      offset_m=ep["es"].qualification.effective_radius_m)

    def _localize(self, init: np.ndarray | None) -> MapResult:
        """Maximum a posteriori on the ball centres (the effective ball radius off the
        surface) with the placement prior, from ``init``."""
        ep = self.episode
        es = ep["es"]
        return localize_map(ep["points"], es.workpiece.index, ep["realized"].T_base_workpiece_nominal, self.prior,
                            self._point_sigma_m(), init=init, edges=es.edges, edge_band_m=self.edge_band_m(),
                            offset_m=es.qualification.effective_radius_m)

    def _point_sigma_m(self) -> float:
        return probe_sigma_m(self.episode["realized"])

    def _joints(self) -> np.ndarray:
        program = self.episode["program"]
        return joint_state_of(program.state, program.cell).copy()

    def _render_scene(self) -> tuple[Cell, np.ndarray]:
        program = self.episode["program"]
        return program.cell, program.state

    def _info_totals(self) -> dict:
        ep = self.episode
        return {"hits_total": ep["hits"], "misses_total": ep["misses"]}


def _qualify(realized: Realized, nominal: Cell) -> Qualification:
    """The probe qualified on the reference sphere in the scenario's own true cell."""
    sc = realized.scenario
    program = ProbingProgram(realized, nominal, build_probe_cell(realized), realized.streams.generator("probe"))
    safe_z = safe_height_world(realized, sc.workpiece.T_world_workpiece_nominal)
    try:
        hits = program.run(qualification_targets(realized), safe_z)
    except TwinError as exc:
        raise ValueError(f"scenario {sc.name!r}: the probe's qualification on the reference sphere failed: {exc}") \
            from None
    missed = sum(not h.hit for h in hits)
    if missed:
        raise ValueError(f"scenario {sc.name!r}: {missed} of {len(hits)} probing moves on the reference sphere found "
                         "no surface: is the sphere where probe.sphere_xyz_m says?")
    return qualify(hits, realized)


def _motion_since(program: ProbingProgram, first: int) -> tuple[float, list]:
    """The duration [s] of the samples the program logged from chunk ``first`` on, and the
    collisions over them (MuJoCo's contact sensors on the arm, the exact probe checks)."""
    chunks = {k: v[first:] for k, v in program.logs.items()}
    if not chunks["t"]:
        return 0.0, []
    t = np.concatenate(chunks["t"])
    contacts = []
    if program.contact_names:
        contacts = contact_records(program.contact_names, np.concatenate(chunks["cdata"], axis=0), t,
                                   program.T_base_world)
    probe, _ = program.probe_contacts(t, np.vstack(chunks["ball"]), np.vstack(chunks["module"]),
                                      np.concatenate(chunks["phase"]))
    return len(t) * program.dt, contacts + probe
