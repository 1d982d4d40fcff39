"""Hybrid (envelopment) localization, Algorithm 3 (algorithms/registration/hybrid.py), on the cast blank."""

from __future__ import annotations

import numpy as np
import pytest

from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import exp_se3, inv_pose, make_pose, transform_points
from algorithms.registration import HybridResult, Status
from algorithms.registration.hybrid import envelope_distances, localize_hybrid
from tests.helpers import scenario
from tests.tolerances import (
    DATUM_COS_TOL,
    DATUM_M,
    EXACT_M,
    FEASIBLE_M,
    LIMIT_MARGIN_M,
    MAX_MIN_OPTIMA_M,
    TRUE_ALLOWANCE_M,
)
from twin.cli.localize import EXIT_UNTRUSTED
from twin.parts.symmetric import (
    cast_blank,
    cast_blank_finished,
    cast_blank_geometry,
    cast_blank_rough_points,
    classify_cast_blank_points,
)

NOISE_M = 2e-6  # default sensor sigma
TIGHT_ALLOWANCE_M = 0.0025  # close to the best achievable (about 2.8 mm): constraints bind
TOO_MUCH_M = 0.0035  # more than the 3 mm nominal stock: infeasible


@pytest.fixture(scope="module")
def parts():
    return {"finished": cast_blank_finished(), "blank": cast_blank(), "geometry": cast_blank_geometry()}


@pytest.fixture(scope="module")
def synthetic(parts):
    """Measured finished (plate top) and rough (dome) points of the blank at a known pose."""
    rng = np.random.default_rng(21)
    g = parts["geometry"]
    L, W, T = g["plate"]
    P = np.column_stack([rng.uniform(-L / 2 + 0.003, L / 2 - 0.003, 2000),
                         rng.uniform(-W / 2 + 0.003, W / 2 - 0.003, 2000), np.full(2000, T)])
    keep = np.ones(len(P), dtype=bool)
    for b in g["bosses"]:
        keep &= np.linalg.norm(P[:, :2] - b["dome_center"][:2], axis=1) > b["dome_base_radius"] + 0.002
    P = P[keep][:400]
    Z, labels = cast_blank_rough_points(600, rng)
    T_true = make_pose(exp_se3([0, 0, np.radians(3.0), 0, 0, 0])[:3, :3], [0.452, 0.118, 0.0])
    T_nom = make_pose(exp_se3([0, 0, np.radians(2.0), 0, 0, 0])[:3, :3], [0.450, 0.120, 0.0])
    Y = transform_points(T_true, P) + rng.normal(0, NOISE_M, P.shape)
    Zw = transform_points(T_true, Z) + rng.normal(0, NOISE_M, Z.shape)
    return {"Y": Y, "Z": Zw, "Z_true": transform_points(T_true, Z), "labels": labels,
            "T_true": T_true, "T_nom": T_nom}


def _true_stock(parts, T_true, T_est, n=20000):
    """Smallest stock [m] of the true blank's domes (as far as a 60 degree beam sees them)
    over the finished part placed at T_est."""
    Zd, _ = cast_blank_rough_points(n, np.random.default_rng(9))
    d, _, _ = envelope_distances(transform_points(T_true, Zd), T_est, MeshIndex(parts["finished"]))
    return float(d.min())


def test_every_rough_point_keeps_its_allowance(parts, synthetic):
    s = synthetic
    res = localize_hybrid(s["Y"], s["Z"], parts["finished"], TIGHT_ALLOWANCE_M, groups=s["labels"],
                          init=s["T_nom"])
    assert isinstance(res, HybridResult) and res.method == "algorithm3"
    assert res.feasible and res.converged and res.status is Status.OK, res.message
    assert res.symmetric.feature == "plane" and res.group_dofs == 3
    assert res.free_dofs == 0  # the two domes fix the in-plane position and the rotation
    # the plate top fixes three directions, the domes the three of G_0; no covariance for those
    assert res.determined_directions.shape == (6, 6) and res.covariance is None
    assert res.symmetric.covariance.shape == (3, 3) and len(res.solutions) == 1
    assert res.margin_m.min() >= -FEASIBLE_M
    # Algorithm 3 lowered the envelope objective from the max-min start, and no feasible
    # small motion along G_0 lowers it further
    index = MeshIndex(parts["finished"])
    d_mm, _, _ = envelope_distances(s["Z"], res.T_max_min, index)
    assert res.envelope_rmse_m <= np.sqrt(np.mean(d_mm**2))
    e = np.sum(res.stock_m**2)
    H = res.symmetric.free_directions
    for k in range(len(H)):
        for t in (1e-5, -1e-5):
            d, _, _ = envelope_distances(s["Z"], res.T_world_workpiece @ exp_se3(t * H[k]), index)
            assert np.sum(d**2) >= e * (1 - 1e-9) or (d - TIGHT_ALLOWANCE_M).min() < 0
    assert set(res.min_allowance_m) == {"boss_a", "boss_b"}
    assert min(res.min_allowance_m.values()) == pytest.approx(res.stock_m.min())
    # against the truth: the measured points' true positions and the whole visible domes
    d_true, _, _ = envelope_distances(s["Z_true"], res.T_world_workpiece, MeshIndex(parts["finished"]))
    assert d_true.min() >= TIGHT_ALLOWANCE_M - TRUE_ALLOWANCE_M
    assert _true_stock(parts, s["T_true"], res.T_world_workpiece) >= TIGHT_ALLOWANCE_M - TRUE_ALLOWANCE_M
    # the finished datum (plate top) is matched: its plane coincides with the truth's
    D = inv_pose(s["T_true"]) @ res.T_world_workpiece
    assert abs(D[2, 3]) < DATUM_M and abs(D[2, 2] - 1.0) < DATUM_COS_TOL


def test_the_answer_does_not_depend_on_round_off_in_the_start(parts, synthetic):
    """Starts 1e-9 to 1e-4 away from the nominal give the same best placement. (The smallest
    margins sit on rough points over finished faces parallel to the plane's motions, flat to
    first order; the max-min used to stop there, reporting 'infeasible' at -0.95 mm, for 4 of
    these 6 starts.)"""
    s = synthetic
    ref = localize_hybrid(s["Y"], s["Z"], parts["finished"], TIGHT_ALLOWANCE_M, groups=s["labels"], init=s["T_nom"])
    rng = np.random.default_rng(0)
    for size in (1.5e-9, 2.6e-9, 4.2e-7, 1e-6, 5.6e-5, 1e-4):
        xi = rng.normal(size=6)
        res = localize_hybrid(s["Y"], s["Z"], parts["finished"], TIGHT_ALLOWANCE_M, groups=s["labels"],
                              init=s["T_nom"] @ exp_se3(xi * size / np.linalg.norm(xi)))
        assert res.feasible, res.message
        # the max-min is a local search: two nearby optima (0.3300 and 0.3327 mm) are reached
        assert res.best_min_margin_m == pytest.approx(ref.best_min_margin_m, abs=MAX_MIN_OPTIMA_M)
        assert res.margin_m.min() == pytest.approx(ref.margin_m.min(), abs=LIMIT_MARGIN_M)


def test_too_little_stock_is_reported_with_the_limiting_points(parts, synthetic):
    s = synthetic
    res = localize_hybrid(s["Y"], s["Z"], parts["finished"], TOO_MUCH_M, groups=s["labels"], init=s["T_nom"])
    assert not res.feasible and not res.trusted
    assert res.status is Status.INFEASIBLE and res.message.startswith("infeasible")
    assert res.best_min_margin_m < 0.0
    assert res.best_min_margin_m == pytest.approx(res.margin_m.min(), abs=EXACT_M)
    # a max-min optimum over 3 parameters rests on at least 2 points, all at the minimum
    lim = res.limiting_points
    assert len(lim) >= 2
    assert np.allclose(res.margin_m[lim], res.best_min_margin_m, atol=LIMIT_MARGIN_M)
    for i in lim[:3]:
        assert f"{i} (" in res.message
    # no placement does better: the max-min is a true optimum (perturbations along G_0 lose)
    H = res.symmetric.free_directions
    index = MeshIndex(parts["finished"])
    for k in range(len(H)):
        for t in (1e-4, -1e-4):
            step = t * H[k] / max(np.linalg.norm(H[k, :3]) * 0.05, np.linalg.norm(H[k, 3:]))
            d, _, _ = envelope_distances(s["Z"], res.T_world_workpiece @ exp_se3(step), index)
            assert (d - TOO_MUCH_M).min() <= res.best_min_margin_m + 1e-9


def test_bad_input_is_refused(parts, synthetic):
    s = synthetic
    fin = parts["finished"]
    with pytest.raises(AlgorithmError, match=r"allowance must be >= 0 .*rough point\(s\) 3 have -0.001"):
        a = np.full(len(s["Z"]), 0.001)
        a[3] = -0.001
        localize_hybrid(s["Y"], s["Z"], fin, a, init=s["T_nom"])
    with pytest.raises(AlgorithmError, match="allowance must be >= 0"):
        localize_hybrid(s["Y"], s["Z"], fin, -0.5, init=s["T_nom"])
    with pytest.raises(AlgorithmError, match="symmetric must be one of auto, none or a feature type"):
        localize_hybrid(s["Y"], s["Z"], fin, 0.001, symmetric="bore", init=s["T_nom"])
    with pytest.raises(AlgorithmError, match="must not be 'none'"):
        localize_hybrid(s["Y"], s["Z"], fin, 0.001, symmetric="none", init=s["T_nom"])
    # two points deep inside boss A (its axis, 5 and 8 mm below its top): not rough points
    g = parts["geometry"]
    T = g["plate"][2]
    a = g["bosses"][0]
    inside = np.array([[a["axis_xy"][0], 0.0, T + a["height"] - 0.005],
                       [a["axis_xy"][0] + 0.003, 0.0, T + a["height"] - 0.008]])
    Z = np.vstack([s["Z"], transform_points(s["T_true"], inside)])
    with pytest.raises(AlgorithmError, match=r"rough point\(s\) 601 \(.* mm inside\), 600 \(.* mm inside\) of 602 "
                                             r"lie inside the finished model by more than"):
        localize_hybrid(s["Y"], Z, fin, 0.001, init=s["T_nom"])


@pytest.mark.slow
def test_cast_blank_scan_through_the_cell_keeps_the_allowance_on_the_true_part(parts):
    from twin.scan import scan_scenario

    sc = scenario("cast_blank", scan={"line_spacing_m": 0.005})
    scan = scan_scenario(sc)
    P = scan.valid_points_base
    T_nom, T_true = scan.T_base_workpiece_nominal, scan.T_base_workpiece_true
    labels = classify_cast_blank_points(transform_points(inv_pose(T_nom), P))
    F, R = P[labels == "finished"], P[labels == "rough"]
    assert len(F) > 1000 and len(R) > 1000
    g = parts["geometry"]
    Rn = transform_points(inv_pose(T_nom), R)
    a = g["bosses"][0]
    groups = np.where(np.linalg.norm(Rn[:, :2] - a["dome_center"][:2], axis=1) < a["dome_base_radius"],
                      "boss_a", "boss_b")
    res = localize_hybrid(F, R, parts["finished"], TIGHT_ALLOWANCE_M, groups=groups, init=T_nom)
    assert res.feasible, res.message
    assert res.margin_m.min() >= -FEASIBLE_M
    # verified against the true part in the cell: the true surface under every measured
    # rough point, and the whole visible domes, keep the allowance
    true_feet = transform_points(T_true, MeshIndex(parts["blank"]).query(transform_points(inv_pose(T_true), R)).foot)
    d_true, _, _ = envelope_distances(true_feet, res.T_world_workpiece, MeshIndex(parts["finished"]))
    assert d_true.min() >= TIGHT_ALLOWANCE_M - TRUE_ALLOWANCE_M
    assert _true_stock(parts, T_true, res.T_world_workpiece) >= TIGHT_ALLOWANCE_M - TRUE_ALLOWANCE_M
    # too much allowance for this casting: infeasible, and the report names the points
    bad = localize_hybrid(F, R, parts["finished"], TOO_MUCH_M, groups=groups, init=T_nom)
    assert not bad.feasible and len(bad.limiting_points) >= 2
    assert bad.status is Status.INFEASIBLE and "limited by point(s)" in bad.message


# ------------------------------------------------------------------------------- the CLI
def _cli(capsys, *argv):
    from twin import cli

    rc = cli.main(["localize", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def hybrid_files(tmp_path_factory, parts, synthetic):
    import json

    from twin.io import write_points_ply

    d = tmp_path_factory.mktemp("hyb_cli")
    parts["finished"].export(d / "finished.ply")
    write_points_ply(d / "finished_pts.ply", synthetic["Y"])
    rows = ["x,y,z,allowance,group"] + [
        f"{p[0]:.9f},{p[1]:.9f},{p[2]:.9f},{TIGHT_ALLOWANCE_M},{g}"
        for p, g in zip(synthetic["Z"], synthetic["labels"], strict=True)]
    (d / "rough.csv").write_text("\n".join(rows) + "\n")
    bad = rows[:4] + [rows[4].replace(f",{TIGHT_ALLOWANCE_M},", ",-0.001,")] + rows[5:]
    (d / "negative.csv").write_text("\n".join(bad) + "\n")
    (d / "noallow.csv").write_text("\n".join(r.rsplit(",", 2)[0] for r in rows) + "\n")
    (d / "init.json").write_text(json.dumps(synthetic["T_nom"].tolist()))
    return d


def test_cli_hybrid_reports_min_allowance_per_group(hybrid_files, capsys):
    import json

    d = hybrid_files
    rc, out, err = _cli(capsys, "--model", d / "finished.ply", "--points", d / "finished_pts.ply",
                        "--allowance", d / "rough.csv", "--init", d / "init.json", "--json")
    assert rc == 0, err
    res = json.loads(out)
    assert res["feasible"] and res["method"] == "algorithm3" and res["feature"] == "plane"
    assert set(res["min_allowance_m"]) == {"boss_a", "boss_b"}
    assert min(res["min_allowance_m"].values()) >= TIGHT_ALLOWANCE_M - FEASIBLE_M
    assert res["free_dofs"] == 0 and len(res["solutions"]) == 1 and res["status"] == "ok"
    # too much allowance: a report (exit 3: finished, not to be trusted), not an error,
    # naming the limiting points
    rc, out, err = _cli(capsys, "--model", d / "finished.ply", "--points", d / "finished_pts.ply",
                        "--allowance", d / "noallow.csv", "--allowance-value", str(TOO_MUCH_M),
                        "--init", d / "init.json", "--json")
    assert rc == EXIT_UNTRUSTED, err
    res = json.loads(out)
    assert not res["feasible"] and res["status"] == "infeasible" and res["message"].startswith("infeasible")
    assert res["best_min_margin_m"] < 0 and len(res["limiting_points"]) >= 2


@pytest.mark.parametrize("csv, extra, message", [
    ("negative.csv", [], "allowance must be >= 0"),
    ("noallow.csv", [], "give the machining allowance"),
    ("rough.csv", ["--symmetric", "none"], "--allowance needs the finished features' symmetry"),
    ("rough.csv", ["--allowance-value", "0.001"], "has an allowance column"),
    ("missing.csv", [], "--allowance file not found"),
])
def test_cli_hybrid_errors_are_one_line(hybrid_files, capsys, csv, extra, message):
    d = hybrid_files
    rc, out, err = _cli(capsys, "--model", d / "finished.ply", "--points", d / "finished_pts.ply",
                        "--allowance", d / csv, "--init", d / "init.json", *extra)
    assert rc == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and message in err
