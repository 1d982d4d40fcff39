"""Does the stated uncertainty cover the error? ``twin localize --scan`` on scans of every shipped
laser scenario, each fit on a new scan: the sensor's noise redrawn and its linearity curve the
one of a new sensor unit (``linearity_phase_deg = "random"``), localized from the nominal pose as
the command does (sigma from the scan's sensor and encoders, the rejection review on), and the
true error's squared Mahalanobis distance against the stated covariance along the determined
directions. A 95 % region that is right holds the error in 95 % of the fits.

    python -m benchmarks.bench_coverage [--fits 500] [--fits-for sphere=100 ...] [--scenarios cube sphere]
                                        [--resolutions-m 0.001 0.0005] [--noise linearity=off ...]
                                        [--workers 2] [--out benchmarks/results_coverage.md]

``--resolutions-m`` runs each scenario once per tessellation of its generated part (the part's
``resolution_m``: its largest edge on curved surfaces), to show what the facets do.
``--noise KEY=on|off`` switches a noise source in every scenario: with the linearity curve and
the quantisation off, what remains is white noise, for which the fit's covariance is the
Cramer-Rao bound, so any shortfall left is the fit's own (the facets along free directions).
"""

from __future__ import annotations

import argparse
import platform
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np
from scipy.stats import beta, chi2

from algorithms.registration.review import localize
from algorithms.registration.uncertainty import nearest_along_free, pose_error_twist
from benchmarks.bench_loop import laser_scenarios
from tests.helpers import ROOT, SCENARIOS, commit_stamp
from twin import evaluate
from twin.io.scan_files import scan_readings
from twin.scan_uncertainty import point_sigma_m, scan_covariance
from twin.scenario import load_scenario
from twin.studies.trials import noise_free_scan, scan_measurement

P = 0.95
CHUNK = 25
#: The scenario's noise switches ``--noise`` may turn on or off.
NOISE_SWITCHES = ("gaussian", "linearity", "quantization", "incidence", "occlusion")


def scenario_of(name: str, resolution_m: float | None = None, noise: dict | None = None):
    over: dict = {"sensor": {"linearity_phase_deg": "random"}}
    if resolution_m is not None:
        over["workpiece"] = {"params": {"resolution_m": resolution_m}}
    if noise:
        over["noise"] = dict(noise)
    return load_scenario(SCENARIOS / f"{name}.toml", over, machine="arm")


def noise_switches(items: list[str]) -> dict:
    """``--noise`` items ``KEY=on|off`` as the scenario's ``[noise]`` overrides."""
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        if key not in NOISE_SWITCHES or value not in ("on", "off"):
            raise SystemExit(f"--noise takes KEY=on|off with KEY one of {', '.join(NOISE_SWITCHES)}, got {item!r}")
        out[key] = value == "on"
    return out


def label(name: str, resolution_m: float | None) -> str:
    return name if resolution_m is None else f"{name} ({resolution_m * 1e3:g} mm facets)"


def determined_error(res, T_true: np.ndarray) -> np.ndarray:
    """The error's coordinates along the result's determined directions: the truth first moved
    along the free directions (the part's symmetry, the same twists in its own frame) to the pose
    nearest the estimate, so that the error twist is taken in the frame the covariance was
    stated in (moving the estimate instead turns that frame by the free rotation, up to tens of
    degrees, and mixes the determined coordinates); then the free part of the twist split off."""
    D = np.asarray(res.determined_directions, dtype=np.float64).reshape(-1, 6)
    F = np.asarray(res.free_directions, dtype=np.float64).reshape(-1, 6)
    xi = pose_error_twist(res.T_world_workpiece, nearest_along_free(T_true, F, res.T_world_workpiece))
    return np.linalg.lstsq(np.vstack([D, F]).T, xi, rcond=None)[0][: len(D)]


def fits(task: tuple[int, str, float | None, int, int, dict]) -> list[dict]:
    """Fits ``first .. first + count - 1`` of one part (at a tessellation, or the scenario's;
    with noise switches overridden, or as the scenario has them)."""
    part, name, resolution_m, first, count, noise = task
    scenario = scenario_of(name, resolution_m, noise)
    geo = noise_free_scan(scenario)
    index = geo.realized.workpiece.index
    T_true = evaluate.Evaluation(geo.realized).T_base_workpiece
    T_nominal = geo.realized.T_base_workpiece_nominal
    rows = []
    for k in range(first, first + count):
        rng = np.random.default_rng(np.random.SeedSequence(2026, spawn_key=(part, k)))
        meas, q_log = scan_measurement(scenario, geo, rng)
        readings = scan_readings(q_log, meas.d, meas.valid, geo.plan.line, geo.sensor.beam_dirs_sensor(),
                                 scenario.sensor, scenario.noise, T_nominal)
        sigma = point_sigma_m(readings.sensor, readings.noise, readings.q, readings.points_base, T_nominal, index)
        t0 = time.perf_counter()
        res = localize(readings.points_base, init=T_nominal, sigma=sigma, index=index)
        cov = scan_covariance(res, readings, index, sigma)
        wall = time.perf_counter() - t0
        row = {"status": res.status.value, "q": 0, "m2": np.nan, "m2_random": np.nan, "region_m2": np.nan,
               "wall_s": wall, "points": len(readings.d)}
        if cov is not None and len(cov.total):
            m = determined_error(res, T_true)
            row.update(q=len(m), m2=float(m @ np.linalg.solve(cov.total, m)),
                       m2_random=float(m @ np.linalg.solve(cov.random, m)), region_m2=cov.region_m2)
        rows.append(row)
    return rows


def interval(k: int, n: int) -> tuple[float, float]:
    """Clopper-Pearson 95 % interval of a proportion k / n."""
    lo = beta.ppf(0.025, k, n - k + 1) if k > 0 else 0.0
    hi = beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    return float(lo), float(hi)


def summary(name: str, rows: list[dict]) -> dict:
    have = [r for r in rows if r["q"] > 0]
    q = np.array([r["q"] for r in have])
    limit = chi2.ppf(P, q)
    m2 = np.array([r["m2"] for r in have])
    inside = int(np.sum(m2 <= np.array([r["region_m2"] for r in have])))
    inside_chi2 = int(np.sum(m2 <= limit))
    inside_random = int(np.sum(np.array([r["m2_random"] for r in have]) <= limit))
    statuses: dict[str, int] = {}
    for r in rows:
        statuses[r["status"]] = statuses.get(r["status"], 0) + 1
    return {"name": name, "fits": len(rows), "with_cov": len(have), "q": sorted(set(q.tolist())),
            "inside": inside, "ci": interval(inside, len(have)), "inside_random": inside_random,
            "inside_chi2": inside_chi2,
            "mean_m2_over_q": float(np.mean([r["m2"] / r["q"] for r in have])) if have else float("nan"),
            "statuses": statuses, "points": int(np.median([r["points"] for r in rows])),
            "fit_s": float(np.median([r["wall_s"] for r in rows]))}


def markdown(results: list[dict], command: str, wall_s: float, noise: dict | None = None) -> str:
    switched = "; ".join(f"{k} {'on' if v else 'off'}" for k, v in (noise or {}).items())
    lines = [
        "# Coverage of the stated 95 % region: `twin localize --scan` on every laser scenario",
        "",
        commit_stamp(),
        "",
        f"Command: `{command}` ({platform.machine()}, {wall_s:.0f} s wall).",
        "",
        *([f"The scenarios' noise switched: {switched} (the others as each scenario has them).", ""] if noise else []),
        "Each fit is on a new scan of the scenario: the sensor's noise redrawn and the linearity curve that of a new",
        "sensor unit (`linearity_phase_deg = \"random\"`, a phase uniform in [0, 360) deg), localized from the nominal",
        "pose as `twin localize --scan DIR --init NOMINAL` does (sigma from the scan's sensor and encoders, the",
        "rejection review and the profile check on). Where the fit leaves directions free, the truth is first moved",
        "along them to the pose nearest the estimate (the error then lies in the frame the covariance is stated in).",
        "`inside` counts the fits whose true error (along the determined directions) lies inside the stated 95 %",
        "region `m^T C^-1 m <= r2`, `r2` the 95 % quantile of the propagated distribution (JCGM 101 Monte Carlo: the",
        "random part Gaussian, the linearity curve's phase uniform; what the command prints as `mahalanobis2_max`);",
        "the interval is Clopper-Pearson 95 %. `chi-square` is the count against the Gaussian radius `chi2_0.95(q)`",
        "instead, and `random only` against the white-noise covariance alone with that radius (what the fit states",
        "from bare points): the linearity curve is what it misses.",
        "",
        "| scenario | fits | q | inside (random and systematic) | 95 % interval | chi-square | mean m2/q "
        "| random only | statuses | points | fit [s] |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        n = r["with_cov"]
        lines.append(
            f"| {r['name']} | {r['fits']} | {','.join(map(str, r['q']))} | {r['inside']}/{n} = "
            f"{100 * r['inside'] / max(n, 1):.1f} % | {100 * r['ci'][0]:.1f}-{100 * r['ci'][1]:.1f} % | "
            f"{100 * r['inside_chi2'] / max(n, 1):.1f} % | "
            f"{r['mean_m2_over_q']:.2f} | {100 * r['inside_random'] / max(n, 1):.1f} % | "
            + ", ".join(f"{k} {v}" for k, v in sorted(r["statuses"].items()))
            + f" | {r['points']} | {r['fit_s']:.2f} |")
    total = sum(r["with_cov"] for r in results)
    inside = sum(r["inside"] for r in results)
    lines += ["", f"All parts: {inside}/{total} = {100 * inside / max(total, 1):.1f} % inside the stated 95 % region.",
              ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fits", type=int, default=500, help="fits per scenario (default 500)")
    ap.add_argument("--fits-for", nargs="*", default=[], metavar="NAME=N", help="another number of fits for a scenario")
    ap.add_argument("--scenarios", nargs="*", default=None, help="scenario names (default: every laser scenario)")
    ap.add_argument("--resolutions-m", type=float, nargs="*", default=None,
                    help="run each scenario at each of these tessellations of its generated part [m]")
    ap.add_argument("--noise", nargs="*", default=[], metavar="KEY=on|off",
                    help=f"switch a noise source of every scenario ({', '.join(NOISE_SWITCHES)})")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results_coverage.md")
    args = ap.parse_args()
    names = args.scenarios or laser_scenarios()
    counts = {name: args.fits for name in names}
    counts.update({k: int(v) for k, v in (item.split("=", 1) for item in args.fits_for)})
    runs = [(name, res) for name in names for res in (args.resolutions_m or [None])]
    noise = noise_switches(args.noise)
    tasks = [(i, name, res, k, min(CHUNK, counts[name] - k), noise) for i, (name, res) in enumerate(runs)
             for k in range(0, counts[name], CHUNK)]
    t0 = time.perf_counter()
    with Pool(args.workers) as pool:
        done = pool.map(fits, tasks, chunksize=1)
    by_part: dict[str, list[dict]] = {label(*run): [] for run in runs}
    for task, rows in zip(tasks, done, strict=True):
        by_part[label(task[1], task[2])].extend(rows)
    results = [summary(name, rows) for name, rows in by_part.items()]
    command = "python -m benchmarks.bench_coverage" + (f" --fits {args.fits}" if args.fits != 500 else "") \
        + (f" --fits-for {' '.join(args.fits_for)}" if args.fits_for else "") \
        + (f" --scenarios {' '.join(names)}" if args.scenarios else "") \
        + (f" --resolutions-m {' '.join(f'{r:g}' for r in args.resolutions_m)}" if args.resolutions_m else "") \
        + (f" --noise {' '.join(args.noise)}" if args.noise else "")
    text = markdown(results, command, time.perf_counter() - t0, noise)
    args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
