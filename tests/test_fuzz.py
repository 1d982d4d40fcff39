"""Property-based fuzzing of the command line (hypothesis): generated meshes, point files,
option combinations and scenario files go through ``twin.cli.main`` in-process.

Every case must end in one of the documented exit statuses with, for a refusal (2), one line
on stderr, nothing on stdout and no output folder; for a finished run, outputs that are
complete and consistent with themselves. An exception escaping ``main`` (a traceback) fails.

CI runs a fixed, derandomized budget (about a minute); ``TWIN_FUZZ=slow pytest -m long
tests/test_fuzz.py`` runs the large random one (2,000 cases).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.helpers import SCENARIOS, sample_surface
from twin.cli import main
from twin.cli.common import EXIT_BAD_INPUT, EXIT_UNTRUSTED
from twin.io import read_points_ply, write_points_ply
from twin.io.output import PARTIAL_MARK
from twin.parts import make_workpiece

SLOW = os.environ.get("TWIN_FUZZ") == "slow"
#: cases per target: (CI, slow); the slow budgets add up to 2,000
BUDGET = {"mesh": (30, 700), "points": (30, 700), "options": (20, 500), "scenario": (4, 100)}


def budget(target: str):
    ci, slow = BUDGET[target]
    return settings(max_examples=slow if SLOW else ci, deadline=None, derandomize=not SLOW,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture],
                    database=None)


def slow_or_ci(fn):
    return pytest.mark.long(fn) if SLOW else fn


# ------------------------------------------------------------------ a valid problem
_DIR = Path(tempfile.mkdtemp(prefix="twin-fuzz-"))
_MESH = make_workpiece("cube")
_PTS, _ = sample_surface(_MESH, 400, np.random.default_rng(0))
_T = np.eye(4)
_T[:3, 3] = [0.45, 0.1, 0.0]
write_points_ply(_DIR / "points.ply", _PTS + _T[:3, 3] + np.random.default_rng(1).normal(0, 5e-6, _PTS.shape))
_MESH.export(_DIR / "model.stl")
(_DIR / "init.json").write_text(json.dumps(_T.tolist()))


def _mesh_text(fmt: str) -> bytes:
    if fmt == "ply_ascii":
        return _MESH.export(file_type="ply", encoding="ascii")
    if fmt == "ply_binary":
        return _MESH.export(file_type="ply")
    if fmt == "stl_ascii":
        return _MESH.export(file_type="stl_ascii").encode()
    if fmt == "stl_binary":
        return _MESH.export(file_type="stl")
    return _MESH.export(file_type="obj").encode()


@st.composite
def mutated(draw, raw: bytes) -> bytes:
    """A valid file changed the ways files go bad: cut, bytes changed, lines changed or
    dropped or repeated, numbers replaced by non-finite, huge or non-numbers, counts off."""
    kind = draw(st.sampled_from(["cut", "bytes", "token", "drop_line", "repeat_line", "count", "random", "none"]))
    if kind == "cut":
        return raw[: draw(st.integers(0, len(raw)))]
    if kind == "bytes":
        b = bytearray(raw)
        for _ in range(draw(st.integers(1, 8))):
            b[draw(st.integers(0, len(b) - 1))] = draw(st.integers(0, 255))
        return bytes(b)
    if kind == "random":
        return draw(st.binary(max_size=400))
    if kind == "none":
        return raw
    try:
        lines = raw.decode("ascii").splitlines()
    except UnicodeDecodeError:  # binary: change the bytes instead
        return raw[:84] + draw(st.binary(min_size=0, max_size=200)) + raw[284:]
    i = draw(st.integers(0, len(lines) - 1))
    if kind == "drop_line":
        del lines[i]
    elif kind == "repeat_line":
        lines.insert(i, lines[i])
    elif kind == "count":
        heads = [k for k, ln in enumerate(lines) if ln.startswith("element")] or [i]
        k = draw(st.sampled_from(heads))
        tok = lines[k].split()
        if len(tok) == 3 and tok[2].isdigit():
            tok[2] = str(max(0, int(tok[2]) + draw(st.integers(-3, 3))))
        lines[k] = " ".join(tok)
    else:  # token
        tok = lines[i].split() or [""]
        j = draw(st.integers(0, len(tok) - 1))
        tok[j] = draw(st.sampled_from(["nan", "inf", "-inf", "1e308", "1e6", "x", "", "-1", "999999", "0"]))
        lines[i] = " ".join(tok)
    return ("\n".join(lines) + "\n").encode("ascii", "replace")


def check_finished(rc: int, out: str, err: str, symmetric: bool = False) -> None:
    """The promises of ``twin localize``: a refusal is one line; a result is one JSON object
    whose trust agrees with the exit status."""
    assert rc in (0, EXIT_BAD_INPUT, EXIT_UNTRUSTED), (rc, err)
    assert "Traceback" not in err
    if rc == EXIT_BAD_INPUT:
        assert out == "" and len(err.strip().splitlines()) == 1, err
        return
    res = json.loads(out)
    T = np.asarray(res["T_world_workpiece"])
    assert T.shape == (4, 4) and np.all(np.isfinite(T))
    assert res["trusted"] == (res["status"] == "ok")
    if rc == 0:
        assert res["trusted"] or (symmetric and res["status"] in ("unobservable", "ambiguous")), res["status"]
    else:
        assert not res["trusted"] or symmetric


def run(capsys, argv) -> tuple[int, str, str]:
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


# ------------------------------------------------------------------ targets
@slow_or_ci
@budget("mesh")
@given(data=st.data(), fmt=st.sampled_from(["ply_ascii", "ply_binary", "stl_ascii", "stl_binary", "obj"]))
def test_fuzz_mesh_files(capsys, data, fmt):
    raw = data.draw(mutated(_mesh_text(fmt)))
    path = _DIR / f"m.{fmt.split('_')[0]}"
    path.write_bytes(raw)
    rc, out, err = run(capsys, ["localize", "--model", path, "--points", _DIR / "points.ply",
                                "--init", _DIR / "init.json", "--json"])
    check_finished(rc, out, err)


@slow_or_ci
@budget("points")
@given(data=st.data(), binary=st.booleans())
def test_fuzz_point_files(capsys, data, binary):
    pts = read_points_ply(_DIR / "points.ply")
    if binary:
        base = (_DIR / "points.ply").read_bytes()
    else:
        base = (f"ply\nformat ascii 1.0\nelement vertex {len(pts)}\nproperty double x\nproperty double y\n"
                "property double z\nend_header\n"
                + "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in pts)).encode()
    path = _DIR / "p.ply"
    path.write_bytes(data.draw(mutated(base)))
    rc, out, err = run(capsys, ["localize", "--model", _DIR / "model.stl", "--points", path,
                                "--init", _DIR / "init.json", "--json"])
    check_finished(rc, out, err)


_OPTIONS = {
    "--method": st.sampled_from(["hong_tan", "icp", "va", "menq", "tangent", "fine_001", "newton", ""]),
    "--init": st.sampled_from(["global", str(_DIR / "init.json"), str(_DIR / "missing.json"),
                               str(_DIR / "points.ply")]),
    "--sigma": st.sampled_from(["5e-6", "1e-3", "0", "-1", "nan", "inf", "abc", "1e-12"]),
    "--units": st.sampled_from(["m", "mm", "inch"]),
    "--outlier": st.sampled_from(["mad", "none", "0.001", "-1", "nan", "far"]),
    "--max-iterations": st.sampled_from(["1", "5", "0", "-3", "1.5", "many"]),
    "--tolerance": st.sampled_from(["1e-9", "0.5", "0", "-1", "nan"]),
    "--seed": st.sampled_from(["0", "7", "-1", "2.5", "99999999999999999999"]),
    "--global-method": st.sampled_from(["multistart", "genetic", "pso", "random"]),
    "--symmetric": st.sampled_from(["auto", "none", "plane", "cylinder", "sphere", "torus"]),
    "--allowance-value": st.sampled_from(["0.001", "-1", "nan"]),
    "--stock": st.sampled_from(["0.001", "0", "x"]),
}


@slow_or_ci
@budget("options")
@given(chosen=st.dictionaries(st.sampled_from(sorted(_OPTIONS)), st.just(None), max_size=4), data=st.data(),
       as_json=st.booleans())
def test_fuzz_localize_options(capsys, chosen, data, as_json):
    argv = ["localize", "--model", _DIR / "model.stl", "--points", _DIR / "points.ply"]
    for opt in chosen:
        argv += [opt, data.draw(_OPTIONS[opt])]
    if as_json:
        argv.append("--json")
    rc, out, err = run(capsys, argv)
    if not as_json and rc != EXIT_BAD_INPUT:
        assert rc in (0, EXIT_UNTRUSTED) and "T_world_workpiece" in out and "Traceback" not in err
        return
    symmetric = "--symmetric" in chosen or "--allowance-value" in chosen
    check_finished(rc, out, err, symmetric=symmetric)


_SCENARIO = (SCENARIOS / "s_surface.toml").read_text().replace('line_axis = "x"', 'line_axis = "x"\nmax_lines = 1')


@slow_or_ci
@budget("scenario")
@given(raw=mutated(_SCENARIO.encode()))
def test_fuzz_scenario_files(capsys, raw):
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        (d / "s.toml").write_bytes(raw)
        out = d / "scan"
        rc, stdout, err = run(capsys, ["scan", d / "s.toml", "--out", out, "--json"])
        assert rc in (0, EXIT_BAD_INPUT), (rc, err)
        assert "Traceback" not in err
        assert not [p for p in d.iterdir() if PARTIAL_MARK in p.name]
        if rc == EXIT_BAD_INPUT:
            assert stdout == "" and len(err.strip().splitlines()) == 1 and not out.exists(), err
            return
        meta = json.loads((out / "scan.json").read_text())
        assert pq.read_metadata(out / "samples.parquet").num_rows == meta["n_samples"] == json.loads(stdout)["samples"]
        assert len(read_points_ply(out / "points.ply")) == meta["n_valid"]
